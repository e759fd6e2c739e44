"""A run directory says whether its run finished: ``summary.json`` is written from the start, while it runs.

``harness run`` writes ``summary.json`` with ``"status": "running"`` (and its process id) before the first
tick and rewrites it every second of wall time with the sim time reached and the vehicles' state so far —
each time right after the recording's chunk in progress went to disk, so the file and ``world.mcap`` agree.
At the end the final status replaces it. A run killed with ``kill -9`` (or a machine that lost power) leaves
``"status": "running"`` behind; :func:`read_summary` reads that as ``"killed"`` once the process is gone,
with the last sim time it recorded. ``harness plot``, the pytest plugin and the sweep read it this way.
"""

from __future__ import annotations

import errno
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec

from harness.core.clock import NS_PER_S, WALL, Clock
from harness.core.files import RecordingError

RUNNING = "running"
KILLED = "killed"
CHECKPOINT_EVERY_S = 1.0


def write_json(path: Path, obj: dict[str, Any]) -> None:
    """Atomically: a reader sees the old file or the new one, never half of one. Raises OSError (and leaves no
    ``.tmp`` behind) when it cannot."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        # msgspec's encoder, not json's: with an indent json encodes in Python (2.5 ms for 300 vehicles, every
        # second while the run runs, against 0.18)
        tmp.write_bytes(msgspec.json.format(msgspec.json.encode(obj), indent=2))
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise


def write_final_json(path: Path, obj: dict[str, Any]) -> None:
    """The last version of ``path``: atomically when there is room; on a full file system, over the old file in
    place and compact (it needs no more space than the indented one it replaces: a run that filled its disk
    still says so in its summary). Raises :class:`RecordingError` when neither works."""
    try:
        write_json(path, obj)
        return
    except OSError as exc:
        if exc.errno not in (errno.ENOSPC, errno.EDQUOT) or not path.is_file():
            raise RecordingError.of(path, exc) from None
        first = exc
    try:
        with path.open("r+b") as f:
            f.write(msgspec.json.encode(obj) + b"\n")
            f.truncate()
    except OSError:
        raise RecordingError.of(path, first) from None


def _proc_stat(pid: int) -> list[str] | None:
    """Fields of ``/proc/<pid>/stat`` after the command name (state first); None when there is no such process."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[-1].split()
    except OSError:
        return None


def _start_time(pid: int) -> str | None:
    """The kernel's start time of process ``pid`` (tells a reused pid apart)."""
    fields = _proc_stat(pid)
    return fields[19] if fields is not None and len(fields) > 19 else None


def _alive(pid: int, started: str | None) -> bool:
    fields = _proc_stat(pid)
    if fields is None:  # no such process (or no /proc: ask the kernel)
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
        return not os.path.isdir("/proc")
    start = fields[19] if len(fields) > 19 else None
    return fields[0] != "Z" and (started is None or start == started)


def read_summary(run_dir: Path) -> dict[str, Any]:
    """``summary.json`` of a run; a run that says "running" but whose process is gone reads as ``"killed"``.
    Raises FileNotFoundError when the run never started."""
    summary: dict[str, Any] = json.loads((run_dir / "summary.json").read_text())
    if summary.get("status") == RUNNING:
        pid = summary.get("pid")
        if not isinstance(pid, int) or not _alive(pid, summary.get("pid_start")):
            summary["status"] = KILLED
            summary["message"] = (
                f"the run did not finish: its process ({pid}) ended without writing a final summary "
                f"(killed or crashed); recorded up to {summary.get('sim_time_s', 0.0):.1f} s of sim time"
            )
    return summary


class Checkpoint:
    """Every ``every_s`` of wall time: ``flush`` (the recording to disk), then ``summary.json`` from ``snapshot``
    with status "running"."""

    def __init__(
        self,
        out: Path,
        snapshot: Callable[[], dict[str, Any]],
        flush: Callable[[], None],
        every_s: float = CHECKPOINT_EVERY_S,
        clock: Clock = WALL,
    ) -> None:
        self.path = out / "summary.json"
        self.clock = clock
        self._snapshot = snapshot
        self._flush = flush
        self._every_ns = int(every_s * NS_PER_S)
        self._last_ns = 0
        self._identity = {"pid": os.getpid(), "pid_start": _start_time(os.getpid())}

    def write(self) -> None:
        """Raises :class:`RecordingError` when ``summary.json`` cannot be written (``flush`` raises its own)."""
        self._last_ns = self.clock.now_ns()
        self._flush()
        try:
            write_json(self.path, self._snapshot() | {"status": RUNNING, "finished": False} | self._identity)
        except OSError as exc:
            raise RecordingError.of(self.path, exc) from None

    def maybe(self) -> None:
        if self.clock.now_ns() - self._last_ns >= self._every_ns:
            self.write()
