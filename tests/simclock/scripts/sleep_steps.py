"""Four sim-time sleeps of 0.5 s, then the time of each wake-up (the lookahead test)."""

import json
import time

start = time.monotonic()
marks = []
for _ in range(4):
    time.sleep(0.5)
    marks.append(time.monotonic() - start)
print(json.dumps(marks))
