"""A fork server for ``python -m MODULE ARGS`` children: import once, fork each child from there.

A mission process spends most of its start-up importing (the interpreter, ``harness.cli``, the sim clock:
about 0.15 CPU-s each); a hundred of them on two cores is seconds before the first tick. The fork server
is one child of the run (``python -m harness.run.forkserver MODULE...``) that imports those modules once
and then forks a child per request, which runs ``MODULE`` as ``__main__`` exactly as ``python -m`` would
(``runpy.run_module``), with the request's argv, environment and output files — a few milliseconds each.

Each forked child has its own process group and is tied to the fork server (``PR_SET_PDEATHSIG``, checked
against the server's pid), and the fork server to the run (:mod:`harness.core.lifeline`): ``kill -9`` of
the run takes all of them. The server reports each child's pid and, once it has reaped it, its exit status.

Protocol over two pipes, one JSON object per line. Requests (run → server):
``{"name", "module", "argv", "env", "unset", "stdout", "stderr", "cwd"}`` (the child's environment is the
server's own with ``env`` set and ``unset`` removed: a request stays small, so that a hundred of them fit
in the pipe before the server has read one); replies (server → run):
``{"started": name, "pid": pid}`` and ``{"exited": pid, "code": code}`` (negative: killed by that signal).
The server exits when the request pipe closes and its last child has been reaped.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import random
import runpy
import select
import subprocess
import sys
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from harness.core import lifeline
from harness.core.clock import NS_PER_S, WALL, Clock


def _run_child(req: dict[str, Any], server: int, fds: Sequence[int]) -> int:
    """In the forked child: become what ``python -m MODULE ARGV`` started with these files would be."""
    os.setpgid(0, 0)
    lifeline.tie_to(server)
    for fd in fds:
        os.close(fd)
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC
    for target, path in ((1, req["stdout"]), (2, req["stderr"])):
        fd = os.open(path, flags, 0o644)
        os.dup2(fd, target)
        os.close(fd)
    r, w = os.pipe()  # stdin at end-of-file (a closed pipe: unlike /dev/null, epoll can wait on it)
    os.close(w)
    os.dup2(r, 0)
    os.close(r)
    os.chdir(req["cwd"])
    for key in req["unset"]:
        os.environ.pop(key, None)
    os.environ.update(req["env"])
    random.seed()  # as a fresh interpreter: not the server's sequence, shared by every child
    sys.argv = [req["module"], *req["argv"]]
    sys.modules.pop(req["module"], None)  # preloaded for its imports; ``python -m`` runs it afresh as __main__
    try:
        runpy.run_module(req["module"], run_name="__main__", alter_sys=True)
    except SystemExit as exc:
        code = exc.code
        return code if isinstance(code, int) else (0 if code is None else 1)
    except BaseException:
        traceback.print_exc()
        return 1
    return 0


def _status(status: int) -> int:
    return -os.WTERMSIG(status) if os.WIFSIGNALED(status) else os.WEXITSTATUS(status)


def serve(req_fd: int, rep_fd: int) -> int:
    """Fork a child per request until the request pipe closes; report starts and exits; reap them all."""
    server = os.getpid()
    children: dict[int, int] = {}  # pidfd -> pid
    pending = b""
    open_ = True

    def reply(obj: dict[str, Any]) -> None:
        os.write(rep_fd, json.dumps(obj).encode() + b"\n")

    while open_ or children:
        ready, _, _ = select.select(([req_fd] if open_ else []) + list(children), [], [])
        for fd in ready:
            if fd == req_fd:
                chunk = os.read(req_fd, 65536)
                if not chunk:
                    open_ = False
                    continue
                pending += chunk
                *lines, pending = pending.split(b"\n")
                for line in lines:
                    req = json.loads(line)
                    sys.stdout.flush()
                    sys.stderr.flush()
                    pid = os.fork()
                    if pid == 0:
                        code = 1
                        try:
                            code = _run_child(req, server, (req_fd, rep_fd, *children))
                        finally:
                            lifeline.exit_now(code)
                    try:
                        os.setpgid(pid, pid)  # as the child does: whichever runs first, the group exists
                    except OSError:
                        pass  # it has exec'd... or already exited: the child's own call did it
                    children[os.pidfd_open(pid)] = pid
                    reply({"started": req["name"], "pid": pid})
            else:
                pid = children.pop(fd)
                os.close(fd)
                _, status = os.waitpid(pid, 0)
                reply({"exited": pid, "code": _status(status)})
    return 0


class ForkServer:
    """The run's side of a fork server: ``spawn`` sends a request, the replies are read as they are needed."""

    def __init__(
        self,
        start: Callable[[list[str], dict[str, str], tuple[int, ...]], subprocess.Popen[bytes]],
        env: dict[str, str],
        preload: Sequence[str],
        clock: Clock = WALL,
    ) -> None:
        """``start(argv, env, pass_fds)`` starts the server process (``Children`` does, as any other child)
        with the environment ``env``."""
        self.clock = clock
        self._env = dict(env)
        req_r, self._req = os.pipe()
        self._rep, rep_w = os.pipe()
        try:
            argv = [sys.executable, "-m", __name__, str(req_r), str(rep_w), *preload]
            self.proc = start(argv, self._env, (req_r, rep_w))
        finally:
            os.close(req_r)
            os.close(rep_w)
        os.set_blocking(self._rep, False)
        self._buf = b""
        self._pids: dict[str, int] = {}
        self._codes: dict[int, int] = {}
        self.gone = False
        """The server has ended (its pipe closed): what it had not reported exited with it."""

    def spawn(self, name: str, module: str, argv: Sequence[str], env: dict[str, str], out: Path, err: Path) -> Forked:
        """``python -m module argv`` as a child of the server, output to ``out`` and ``err``."""
        base = self._env
        changed = {k: v for k, v in env.items() if base.get(k) != v}
        req = {"name": name, "module": module, "argv": list(argv), "env": changed, "unset": sorted(base.keys() - env)}
        req |= {"stdout": str(out), "stderr": str(err), "cwd": os.getcwd()}
        try:
            os.write(self._req, json.dumps(req).encode() + b"\n")
        except BrokenPipeError:
            self.gone = True
        return Forked(self, name)

    def pid_of(self, name: str) -> int | None:
        return self._pids.get(name)

    def code_of(self, pid: int) -> int | None:
        return self._codes.get(pid)

    def read(self, timeout_s: float | None) -> None:
        """Take what the server has reported, waiting up to ``timeout_s`` for something (None: forever)."""
        if self.gone:
            return
        ready, _, _ = select.select([self._rep], [], [], timeout_s)
        if not ready:
            return
        while True:
            try:
                chunk = os.read(self._rep, 65536)
            except BlockingIOError:
                break
            if not chunk:
                self.gone = True
                os.close(self._rep)
                break
            self._buf += chunk
        *lines, self._buf = self._buf.split(b"\n")
        for line in lines:
            msg = json.loads(line)
            if "started" in msg:
                self._pids[msg["started"]] = msg["pid"]
            else:
                self._codes[msg["exited"]] = msg["code"]

    def close(self) -> None:
        """No more requests: the server ends once its children have."""
        with contextlib.suppress(OSError):
            os.close(self._req)


class Forked:
    """A child started by the fork server, for ``Children`` as a ``Popen`` is: pid, poll, wait, returncode."""

    def __init__(self, server: ForkServer, name: str) -> None:
        self.server = server
        self.name = name
        self.returncode: int | None = None

    @property
    def pid(self) -> int | None:
        """None until the server has reported it (or when it never forked it)."""
        self.server.read(0)
        return self.server.pid_of(self.name)

    def poll(self) -> int | None:
        if self.returncode is None:
            pid = self.pid
            code = self.server.code_of(pid) if pid is not None else None
            if code is None and self.server.gone:
                code = -9  # the server is gone, and the kernel took its children with it (or it never forked)
            self.returncode = code
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        clock = self.server.clock
        deadline = None if timeout is None else clock.now_ns() + int(timeout * NS_PER_S)
        while (code := self.poll()) is None:
            left = None if deadline is None else (deadline - clock.now_ns()) / NS_PER_S
            if left is not None and left <= 0:
                raise subprocess.TimeoutExpired(self.name, timeout or 0.0)
            self.server.read(left)
        return code


def main(argv: Sequence[str] | None = None) -> int:
    lifeline.hold_on()  # started by a run (Children): die with it, before anything else
    args = list(sys.argv[1:] if argv is None else argv)
    req_fd, rep_fd, *preload = args
    for module in preload:
        if module.endswith("?"):  # where it imports: else each child meets (and reports) the failure itself
            with contextlib.suppress(Exception):
                importlib.import_module(module[:-1])
        else:
            importlib.import_module(module)
    return serve(int(req_fd), int(rep_fd))


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)  # at once: the run waits for this exit, and tearing down the imports is of no use to anyone
