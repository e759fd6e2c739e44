"""The child processes of a run (``harness run``, ``harness join``): own process groups, no orphans."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Protocol, TextIO

from harness.core import lifeline
from harness.core.clock import NS_PER_S, WALL, Clock
from harness.run.forkserver import ForkServer


class Child(Protocol):
    """What ``Children`` needs of a child: a ``subprocess.Popen``, or one forked by the fork server."""

    @property
    def pid(self) -> int | None: ...

    returncode: int | None

    def poll(self) -> int | None: ...

    def wait(self, timeout: float | None = None) -> int: ...


class Children:
    """The run's child processes: output to files in the run directory, stopped as process groups.

    Every child runs in its own process group and is SIGKILLed by the kernel if this process dies; on
    ``stop()`` each group gets SIGTERM, then SIGKILL after ``grace_s``. Nothing outlives the run.

    Each child is a harness entry point that ties itself to this process first thing
    (:func:`harness.core.lifeline.hold_on`): no ``preexec_fn``, so ``subprocess`` spawns it with ``vfork``
    instead of copying this whole process (``docs/architecture.md``, start-up).
    """

    def __init__(
        self, run_dir: Path, grace_s: float = 2.0, clock: Clock = WALL, fork_preload: Sequence[str] = ()
    ) -> None:
        """``fork_preload``: what the fork server imports before it forks (:meth:`start` with ``forked``)."""
        self.run_dir = run_dir
        self.grace_s = grace_s
        self.clock = clock
        self.fork_preload = tuple(fork_preload)
        self.procs: dict[str, Child] = {}
        self._reported: set[str] = set()
        self._server: ForkServer | None = None

    def __enter__(self) -> Children:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(
        self, name: str, argv: list[str], env: dict[str, str], forked: bool = False, terminal: bool = False
    ) -> Child:
        """Start ``argv`` (a harness entry point: it calls ``lifeline.hold_on`` first thing). ``forked``: a
        ``python -m MODULE ...`` command is forked from the run's fork server instead (started with the
        first such child), which has imported ``fork_preload`` already: no interpreter start-up, no imports.
        ``terminal``: this process's stdin goes to the child, its output to this process's as well as to the
        files (``harness run --stdin``); otherwise the child's stdin is at end-of-file from the start."""
        out, err = self.run_dir / f"{name}.stdout", self.run_dir / f"{name}.stderr"
        proc: Child
        if terminal:
            proc = self._spawn_on_terminal(name, argv, env)
        elif forked and argv[:2] == [sys.executable, "-m"]:
            if self._server is None:
                self._server = ForkServer(
                    lambda a, e, fds: self._spawn("forkserver", a, e, fds), env, self.fork_preload, self.clock
                )
                self.procs["forkserver"] = self._server.proc
            proc = self._server.spawn(name, argv[2], argv[3:], env, out, err)
        else:
            proc = self._spawn(name, argv, env)
        self.procs[name] = proc
        return proc

    def _spawn(
        self, name: str, argv: list[str], env: dict[str, str], pass_fds: tuple[int, ...] = ()
    ) -> subprocess.Popen[bytes]:
        with (self.run_dir / f"{name}.stdout").open("wb") as out, (self.run_dir / f"{name}.stderr").open("wb") as err:
            proc = subprocess.Popen(
                argv,
                stdin=subprocess.PIPE,  # closed at once: end-of-file (on /dev/null epoll fails with EPERM)
                stdout=out,
                stderr=err,
                env=lifeline.tied_env(env),
                process_group=0,
                pass_fds=pass_fds,
            )
        assert proc.stdin is not None
        proc.stdin.close()
        return proc

    def _spawn_on_terminal(self, name: str, argv: list[str], env: dict[str, str]) -> subprocess.Popen[bytes]:
        """The child reads what is typed here and its output shows here too, through pipes: it keeps its own
        process group (stopped with the others) and never reads the terminal itself."""
        proc = subprocess.Popen(
            argv,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env=lifeline.tied_env({**env, "PYTHONUNBUFFERED": "1"}),  # a prompt shows before the script waits
            process_group=0,
        )
        assert proc.stdin is not None and proc.stdout is not None and proc.stderr is not None
        pumps = (
            (_copy_stdin, (proc.stdin,)),
            (_tee, (proc.stdout, self.run_dir / f"{name}.stdout", sys.stdout)),
            (_tee, (proc.stderr, self.run_dir / f"{name}.stderr", sys.stderr)),
        )
        for fn, args in pumps:
            threading.Thread(target=fn, args=args, name=f"{name}-terminal", daemon=True).start()
        return proc

    def poll_exits(self) -> list[tuple[str, int]]:
        """Children that exited since the last call: (name, exit code; negative = killed by signal)."""
        out = []
        for name, proc in self.procs.items():
            if name not in self._reported and (code := proc.poll()) is not None:
                self._reported.add(name)
                out.append((name, code))
        return out

    def stop(self) -> None:
        server = None
        if self._server is not None:
            self._server.close()  # no more forks: it reports its children's ends and exits after the last
            server = self._server.proc
        live = [p for p in self.procs.values() if p.poll() is None]
        for proc in live:
            if proc is not server:
                _signal_group(proc, signal.SIGTERM)
        deadline = self.clock.now_ns() + int(self.grace_s * NS_PER_S)
        for proc in live:
            left = max(0.0, (deadline - self.clock.now_ns()) / NS_PER_S)
            try:
                proc.wait(left)
            except subprocess.TimeoutExpired:
                pass
        for proc in self.procs.values():
            _signal_group(proc, signal.SIGKILL)  # the group: grandchildren such as mavsdk_server too
            proc.wait()


def _copy_stdin(to: IO[bytes]) -> None:
    """This process's stdin to a child, until either side closes."""
    try:
        while data := os.read(0, 4096):
            to.write(data)
            to.flush()
    except OSError:
        pass
    with contextlib.suppress(OSError):
        to.close()


def _tee(src: IO[bytes], path: Path, shown: TextIO) -> None:
    """A child's output to its file in the run directory and to this process's ``shown``."""
    with path.open("wb") as out:
        while data := os.read(src.fileno(), 65536):
            out.write(data)
            out.flush()
            with contextlib.suppress(OSError, ValueError):
                shown.buffer.write(data)
                shown.flush()


def _signal_group(proc: Child, sig: int) -> None:
    pid = proc.pid
    if pid is not None:  # None: a fork the server never made (it dies with the server)
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(pid, sig)
