"""A worker thread whose work reads the clock 2,500 times (the clock-read limit stops it twice, so it finishes two
phases after it started) and a main thread that polls for its result with ``time.sleep``, in the style of DroneKit's
``wait_ready`` while its reader takes in a parameter list. Five rounds; each prints when the worker finished and
when the main thread saw it (sim time since the round began): the same at any pace."""

import threading
import time


def work(result: list[float]) -> None:
    for _ in range(2_500):
        time.monotonic()
    result.append(time.monotonic())


for k in range(5):
    result: list[float] = []
    t0 = time.monotonic()
    worker = threading.Thread(target=work, args=(result,))
    worker.start()
    while not result:
        time.sleep(0.02)
    seen = time.monotonic()
    worker.join()
    print(f"round {k}: finished at {result[0] - t0:.3f} s, seen at {seen - t0:.3f} s")
    time.sleep(0.05)
