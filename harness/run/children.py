"""The child processes of a run (``harness run``, ``harness join``): own process groups, no orphans."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
from pathlib import Path

from harness.core import lifeline
from harness.core.clock import NS_PER_S, WALL, Clock


class Children:
    """The run's child processes: output to files in the run directory, stopped as process groups.

    Every child runs in its own process group and is SIGKILLed by the kernel if this process dies; on
    ``stop()`` each group gets SIGTERM, then SIGKILL after ``grace_s``. Nothing outlives the run.

    Each child is a harness entry point that ties itself to this process first thing
    (:func:`harness.core.lifeline.hold_on`): no ``preexec_fn``, so ``subprocess`` spawns it with ``vfork``
    instead of copying this whole process (``docs/architecture.md``, start-up).
    """

    def __init__(self, run_dir: Path, grace_s: float = 2.0, clock: Clock = WALL) -> None:
        self.run_dir = run_dir
        self.grace_s = grace_s
        self.clock = clock
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self._reported: set[str] = set()

    def __enter__(self) -> Children:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self, name: str, argv: list[str], env: dict[str, str]) -> subprocess.Popen[bytes]:
        out = (self.run_dir / f"{name}.stdout").open("wb")
        err = (self.run_dir / f"{name}.stderr").open("wb")
        proc = subprocess.Popen(
            argv, stdin=subprocess.DEVNULL, stdout=out, stderr=err, env=lifeline.tied_env(env), process_group=0
        )
        out.close()
        err.close()
        self.procs[name] = proc
        return proc

    def poll_exits(self) -> list[tuple[str, int]]:
        """Children that exited since the last call: (name, exit code; negative = killed by signal)."""
        out = []
        for name, proc in self.procs.items():
            if name not in self._reported and proc.poll() is not None:
                self._reported.add(name)
                out.append((name, proc.returncode))
        return out

    def stop(self) -> None:
        live = [p for p in self.procs.values() if p.poll() is None]
        for proc in live:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(proc.pid, signal.SIGTERM)
        deadline = self.clock.now_ns() + int(self.grace_s * NS_PER_S)
        for proc in live:
            left = max(0.0, (deadline - self.clock.now_ns()) / NS_PER_S)
            try:
                proc.wait(left)
            except subprocess.TimeoutExpired:
                pass
        for proc in self.procs.values():
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(proc.pid, signal.SIGKILL)  # the group: grandchildren such as mavsdk_server too
            proc.wait()
