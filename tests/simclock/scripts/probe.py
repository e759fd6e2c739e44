"""One wait of one kind that must take 2 s of sim time (issue 33): ``probe.py KIND``.

Prints ``{"kind": KIND, "dt": <sim seconds the wait took>, "ok": <what the wait returned was right>}``; the
seconds are read with ``time.time()`` (sim time in a mission), or with the clock under test."""

from __future__ import annotations

import json
import sys
import time

KIND = sys.argv[1]
SECONDS = 2.0


def _sleep_target() -> None:
    time.sleep(SECONDS)


def _process(method: str) -> bool:
    import multiprocessing

    p = multiprocessing.get_context(method).Process(target=_sleep_target)
    p.start()
    p.join(60)
    return p.exitcode == 0


def _subprocess() -> bool:
    import subprocess

    return subprocess.run([sys.executable, "-c", f"import time; time.sleep({SECONDS})"], check=False).returncode == 0


def _nested_subprocess() -> bool:
    """A child that starts its own child and waits for it: the grandchild's exit status reaches the child."""
    import subprocess

    inner = f"import subprocess, sys; sys.exit(subprocess.run(['sh', '-c', 'sleep {int(SECONDS)}; exit 3']).returncode)"
    return subprocess.run([sys.executable, "-c", inner], check=False).returncode == 3


def _asyncio_subprocess() -> bool:
    import asyncio

    async def main() -> int:
        proc = await asyncio.create_subprocess_exec("sleep", str(int(SECONDS)))
        return await proc.wait()

    return asyncio.run(main()) == 0


def _lock() -> bool:
    import threading

    lock = threading.Lock()
    lock.acquire()
    return lock.acquire(timeout=SECONDS) is False


def _simple_queue() -> bool:
    import queue

    try:
        queue.SimpleQueue().get(timeout=SECONDS)
    except queue.Empty:
        return True
    return False


def _usleep() -> bool:
    import ctypes

    return ctypes.CDLL(None).usleep(int(SECONDS * 1_000_000)) == 0


def _zmq_poll() -> bool:
    import zmq

    ctx = zmq.Context()
    sock = ctx.socket(zmq.PULL)
    sock.bind("inproc://probe")
    events = sock.poll(int(SECONDS * 1000))
    sock.close(0)
    ctx.term()
    return events == 0


class _Fired(Exception):
    pass


def _setitimer() -> bool:
    import signal

    def fire(signum: int, frame: object) -> None:
        raise _Fired

    signal.signal(signal.SIGALRM, fire)
    signal.setitimer(signal.ITIMER_REAL, SECONDS)
    try:
        time.sleep(10 * SECONDS)
    except _Fired:
        return True
    return False


PROBES = {
    "process_fork": lambda: _process("fork"),
    "process_forkserver": lambda: _process("forkserver"),
    "process_spawn": lambda: _process("spawn"),
    "subprocess": _subprocess,
    "nested_subprocess": _nested_subprocess,
    "asyncio_subprocess": _asyncio_subprocess,
    "lock": _lock,
    "simple_queue": _simple_queue,
    "usleep": _usleep,
    "zmq_poll": _zmq_poll,
    "setitimer": _setitimer,
}

if __name__ == "__main__":
    if KIND == "clock_gettime":
        c0 = time.clock_gettime(time.CLOCK_MONOTONIC)
        time.sleep(SECONDS)
        result = {"kind": KIND, "dt": round(time.clock_gettime(time.CLOCK_MONOTONIC) - c0, 6), "ok": True}
    else:
        t0 = time.time()
        ok = PROBES[KIND]()
        result = {"kind": KIND, "dt": round(time.time() - t0, 6), "ok": ok}
    print(json.dumps(result), flush=True)
