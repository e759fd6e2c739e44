"""Test mission: report a metric, then wait (sim-time sleeps) until the file given as argument exists.

An argument that exists already ends the mission at once; one that does not keeps the run going until the
test creates it (or the run is stopped). The argument ``fail`` makes the mission exit with status 3."""

import os
import sys
import time
from pathlib import Path

from harness.metrics import report

flag = Path(sys.argv[1])
start = time.monotonic()  # sim time
report(vehicle=int(os.environ["HARNESS_VEHICLE"]))
if sys.argv[1] == "fail":
    sys.exit(3)
while not flag.exists():
    time.sleep(0.5)
report(waited_s=time.monotonic() - start)
