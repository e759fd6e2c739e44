"""Rerun viewers for the 3D view: the native viewer as a supervised child, the web viewer served in-process.

- ``WebViewer``: serves Rerun's web viewer (its assets ship inside the ``rerun-sdk`` wheel; no internet)
  over HTTP and gives the URL that connects it to a run's live stream.
- ``NativeViewer``: starts the ``rerun`` viewer on a live stream or a ``world.rrd``; it runs in its own
  process group and is killed by the kernel if this process dies, so it never outlives the harness.
"""

from __future__ import annotations

import contextlib
import enum
import importlib.util
import os
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path
from urllib.parse import quote

from harness.core import lifeline
from harness.core.errors import ScenarioError
from harness.core.freeport import free_tcp_port
from harness.record.sink import INSTALL_HINT, rerun_available


class ViewMode(enum.Enum):
    NATIVE = "native"
    WEB = "web"


def _check_free(port: int, option: str) -> None:
    """The web viewer's port can be listened on (on every address, as its server does)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("0.0.0.0", port))
            s.listen()
        except OSError as exc:
            raise ScenarioError(
                f"{option} {port}: the port cannot be listened on ({exc.strerror}): choose another, or leave "
                f"{option} out for a free one"
            ) from None


def require_rerun(what: str) -> None:
    if not rerun_available():
        raise ScenarioError(f"{what} needs Rerun, which is not installed: {INSTALL_HINT}")


def rerun_executable() -> str:
    """The ``rerun`` viewer binary of the environment ``harness`` runs in (the wheel ships it). The binary
    itself, not the ``bin/rerun`` Python wrapper, so that killing it (and its death with us) leaves no child."""
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin is not None:
        binary = Path(spec.origin).parent / "rerun"
        if binary.is_file():
            return str(binary)
    here = Path(sys.executable).parent / "rerun"
    if here.is_file():
        return str(here)
    found = shutil.which("rerun")
    if found is None:
        raise ScenarioError(f"the rerun viewer executable was not found: {INSTALL_HINT}")
    return found


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or sys.platform in ("darwin", "win32")


class WebViewer:
    """Rerun's web viewer over HTTP on ``port`` (all interfaces, for remote machines); lives as long as this
    process (Rerun's server has no stop)."""

    def __init__(self, port: int | None = None, option: str = "--view-port") -> None:
        """``port``: the one the user asked for (``option``), tried now: in use, it is one line before the run."""
        require_rerun("the web viewer")
        if port:
            _check_free(port, option)
        self.port = port or free_tcp_port()
        self._started = False

    def url(self, connect_to: str) -> str:
        """The address a browser opens to watch the stream ``connect_to`` (a ``rerun+http://…/proxy``)."""
        return f"http://127.0.0.1:{self.port}/?url={quote(connect_to, safe=':/')}"

    def start(self, connect_to: str) -> str:
        import rerun as rr

        if not self._started:
            rr.serve_web_viewer(web_port=self.port, open_browser=False, connect_to=connect_to)
            self._started = True
        return self.url(connect_to)


def _viewer_env() -> dict[str, str]:
    """The viewer logs warnings and errors only (its info lines would drown the run's output)."""
    return dict(os.environ, RUST_LOG=os.environ.get("RUST_LOG", "warn"))


class NativeViewer:
    """The native ``rerun`` viewer as a child process (needs a display)."""

    def __init__(self, source: str, extra_args: tuple[str, ...] = ()) -> None:
        require_rerun("the native viewer")
        if not has_display():
            raise ScenarioError(
                "the native viewer needs a display (DISPLAY is not set): use the web viewer instead "
                "(harness run --view web, harness view RUNDIR --web)"
            )
        self.argv = [rerun_executable(), *extra_args, source]
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> NativeViewer:
        self.proc = subprocess.Popen(
            self.argv, stdin=subprocess.DEVNULL, env=_viewer_env(), preexec_fn=lifeline.preexec
        )
        return self

    def wait(self) -> int:
        assert self.proc is not None
        return self.proc.wait()

    def stop(self, grace_s: float = 2.0) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGTERM)
        try:
            self.proc.wait(grace_s)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()


def serve_file_web(rrd: Path, web_port: int | None = None) -> tuple[subprocess.Popen[bytes], str]:
    """``rerun --serve-web`` on a recording, as a supervised child; returns it and the URL to open."""
    require_rerun("the web viewer")
    if web_port:
        _check_free(web_port, "--port")
    port = web_port or free_tcp_port()
    grpc_port = free_tcp_port()
    proc = subprocess.Popen(
        [rerun_executable(), "--serve-web", "--web-viewer-port", str(port), "--port", str(grpc_port), str(rrd)],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        env=_viewer_env(),
        preexec_fn=lifeline.preexec,
    )
    connect = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
    return proc, f"http://127.0.0.1:{port}/?url={quote(connect, safe=':/')}"
