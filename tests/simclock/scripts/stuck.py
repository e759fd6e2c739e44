"""Stuck outside every sim-time wait: ``stuck.py lock`` (the main thread in an untimed Lock.acquire on a held lock)
or ``stuck.py child`` (a child process doing the same): the mission's warning must say which call it is in."""

import subprocess
import sys
import threading

if sys.argv[1] == "lock":
    lock = threading.Lock()
    lock.acquire()
    lock.acquire()
else:
    code = "import threading; lock = threading.Lock(); lock.acquire(); lock.acquire()"
    subprocess.run([sys.executable, "-c", code], check=False)
