"""A plain script: time.sleep(5) must take 5 s of sim time."""

import json
import sys
import time

t0, m0, p0 = time.time(), time.monotonic(), time.perf_counter()
time.sleep(float(sys.argv[1]) if len(sys.argv) > 1 else 5.0)
print(json.dumps({"time": time.time() - t0, "monotonic": time.monotonic() - m0, "perf": time.perf_counter() - p0}))
