"""time.time() moves only with ticks: constant while the script computes, forward after a sleep."""

import json
import time

t1 = time.time()
spin_until = time.process_time() + 0.05  # 50 ms of real CPU work (process_time is not patched)
while time.process_time() < spin_until:
    pass
t2 = time.time()
time.sleep(0.001)
t3 = time.time()
print(json.dumps({"during_work": t2 - t1, "after_sleep": t3 - t2}))
