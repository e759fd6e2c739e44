"""Waits by polling the clock, never sleeping: ``time.time()`` in a loop until 5 s have passed, then the
same with ``time.monotonic()``; prints when each wait ended (sim seconds since the start)."""

import time

start = time.monotonic()
until = time.time() + 5.0
spins = 0
while time.time() < until:
    spins += 1
print(f"time.time waited until {time.monotonic() - start:.3f} s after {spins} reads")
until = time.monotonic() + 2.0
while time.monotonic() < until:
    pass
print(f"time.monotonic waited until {time.monotonic() - start:.3f} s")
