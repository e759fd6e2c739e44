"""Threads started by the script, a new_event_loop, Event.wait and Queue timeouts all follow sim time."""

import asyncio
import json
import queue
import threading
import time

results = {}


def worker() -> None:
    t0 = time.monotonic()
    time.sleep(2)
    results["thread_sleep"] = time.monotonic() - t0
    ev = threading.Event()
    t0 = time.monotonic()
    results["event_set"] = ev.wait(1.5)
    results["event_wait"] = time.monotonic() - t0


th = threading.Thread(target=worker)
th.start()
loop = asyncio.new_event_loop()
t0 = loop.time()
loop.run_until_complete(asyncio.sleep(3))
results["new_loop_sleep"] = loop.time() - t0
loop.close()
q: queue.Queue[int] = queue.Queue()
t0 = time.monotonic()
try:
    q.get(timeout=0.5)
except queue.Empty:
    results["queue_timeout"] = time.monotonic() - t0
th.join()
print(json.dumps(results))
