"""Never idle: an event loop that only yields (``await asyncio.sleep(0)``) until 3 s of sim time have passed,
then a thread that sends its vehicle datagrams in a loop without waiting until 2 s more have passed."""

import asyncio
import socket
import time


async def spin() -> int:
    loop = asyncio.get_running_loop()
    n = 0
    while loop.time() < 3.0:
        n += 1
        await asyncio.sleep(0)
    return n


start = time.monotonic()
n = asyncio.run(spin())
print(f"event loop: 3 s of sim passed after {n} turns at {time.monotonic() - start:.3f} s")
sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
sent = 0
while time.monotonic() - start < 5.0:
    sock.sendto(b"\xfd\x00", ("127.0.0.1", 14540))
    sent += 1
print(f"sender: {sent} datagrams, ended at {time.monotonic() - start:.3f} s")
