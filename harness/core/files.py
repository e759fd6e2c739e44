"""Files a user names and files a run writes: every way they fail as one line that names the path and says
what to do.

Inputs (a scenario file, a mission script, a key file) fail before anything starts, as a
:class:`~harness.core.errors.ScenarioError`: missing, a directory, unreadable, not UTF-8. The run directory is
tried before anything starts (:func:`writable_dir`). A write that fails while the run goes on (the disk filled
up, the file system went read-only) is a :class:`RecordingError`: the run stops and fails, and says which file.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import TypeVar

import msgspec

from harness.core.errors import ScenarioError, SimulationError

_Config = TypeVar("_Config")

_HINTS = {
    errno.ENOSPC: "the file system is full: free space there or give --out a directory on another one",
    errno.EDQUOT: "the disk quota is used up: free space or give --out a directory elsewhere",
    errno.EROFS: "the file system is read-only: give --out a writable directory",
    errno.EACCES: "permission denied: give --out a directory you can write to",
    errno.EPERM: "permission denied: give --out a directory you can write to",
    errno.ENOTDIR: "a file stands where a directory is expected: give --out a directory",
    errno.EEXIST: "a file stands where a directory is expected: give --out a directory",
    errno.ENOENT: "the run directory was removed while the run went on",
}


def reason(exc: OSError) -> str:
    """What the system said (``No space left on device``), without the ``[Errno 28]`` and the path."""
    return exc.strerror or str(exc)


def write_hint(exc: OSError) -> str:
    """What to do about a write that failed with ``exc``."""
    return _HINTS.get(exc.errno or 0, "check the file system it is on")


class RecordingError(SimulationError):
    """A file of the run could not be written while it ran: the recording is incomplete."""

    def __init__(self, path: Path, why: str, hint: str) -> None:
        self.path = path
        super().__init__(f"could not write {path}: {why} ({hint}); the recording is incomplete")

    @classmethod
    def of(cls, path: Path, exc: OSError) -> RecordingError:
        return cls(path, reason(exc), write_hint(exc))

    @classmethod
    def writer_stopped(cls, path: Path, why: str) -> RecordingError:
        """A writer that gives no errno (Rerun's file sink): the file system's state tells what to do."""
        full = free_bytes(path.parent) < FULL_BELOW_BYTES
        return cls(path, why, _HINTS[errno.ENOSPC] if full else "check the file system it is on")


def first_per_file(errors: list[RecordingError]) -> list[RecordingError]:
    """The first failure of each file, in the order they were found."""
    seen: dict[Path, RecordingError] = {}
    for e in errors:
        seen.setdefault(e.path, e)
    return list(seen.values())


def lost_message(lost: list[RecordingError]) -> str:
    """The run's message for the recordings it could not complete: the first in full, the others by name."""
    more = "; also " + ", ".join(str(e.path) for e in lost[1:]) if len(lost) > 1 else ""
    return str(lost[0]) + more


FULL_BELOW_BYTES = 1 << 20
"""Less free space than this where a writer stopped: the file system is (as good as) full."""


def free_bytes(directory: Path) -> int:
    """Space left for this user on ``directory``'s file system (a large number when it cannot be told)."""
    try:
        st = os.statvfs(directory)
    except OSError:
        return 1 << 62
    return st.f_bavail * st.f_frsize


def read_text(path: Path, what: str, max_bytes: int | None = None) -> str:
    """The text of an input file, or one line saying why it cannot be used (``what``: how the user named it,
    e.g. ``scenario file``, ``--mission``; ``max_bytes``: larger is refused unread)."""
    try:
        size = path.stat().st_size if max_bytes is not None else 0
        if max_bytes is not None and size > max_bytes:
            raise ScenarioError(f"{what} {path}: {size:,} bytes, more than the {max_bytes:,} it may have") from None
        data = path.read_bytes()
    except FileNotFoundError:
        raise ScenarioError(f"{what} {path}: the file does not exist") from None
    except IsADirectoryError:
        raise ScenarioError(f"{what} {path}: this is a directory; give the path of a file") from None
    except PermissionError:
        raise ScenarioError(f"{what} {path}: permission denied (make it readable: chmod u+r)") from None
    except OSError as exc:
        raise ScenarioError(f"{what} {path}: cannot be read ({reason(exc)})") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise ScenarioError(
            f"{what} {path}: not UTF-8 text (byte 0x{data[exc.start]:02x} on line {line}); save it as UTF-8"
        ) from None


def script_file(path: Path, what: str) -> Path:
    """``path`` when it is a readable file; else one line saying what it is instead."""
    if not path.exists():
        raise ScenarioError(f"{what} {path}: the file does not exist")
    if path.is_dir():
        raise ScenarioError(f"{what} {path}: this is a directory; give the path of a script")
    if not path.is_file():
        raise ScenarioError(f"{what} {path}: not a regular file; give the path of a script")
    if not os.access(path, os.R_OK):
        raise ScenarioError(f"{what} {path}: permission denied (make it readable: chmod u+r)")
    return path


PROBE = ".harness-write-test"


def writable_dir(path: Path, what: str = "run directory") -> None:
    """Create the run directory ``path`` and write a few bytes in it, or say in one line why that fails (a
    read-only or full file system, a file in the way, no permission) — before anything starts."""
    probe = path / PROBE
    if path.exists() and not path.is_dir():
        raise ScenarioError(f"{what} {path}: this is a file, not a directory; give --out a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
        with probe.open("wb") as f:
            f.write(b"uav-harness\n" * 16)
            f.flush()
            os.fsync(f.fileno())  # a file system that reserves space late (NFS, quotas) says so now
    except OSError as exc:
        at = f" ({exc.filename})" if exc.filename and Path(exc.filename) not in (path, probe) else ""
        raise ScenarioError(f"{what} {path}: cannot write there{at}: {reason(exc)}; {write_hint(exc)}") from None
    finally:
        try:
            probe.unlink()
        except OSError:
            pass


def read_child_config(path: Path, kind: type[_Config], what: str) -> _Config:
    """A child process's typed configuration (``--config FILE``, written by ``harness run``) as ``kind``;
    :class:`ScenarioError` naming the file when it cannot be read or is not ``what``."""
    try:
        return msgspec.json.decode(path.read_bytes(), type=kind)
    except OSError as exc:
        raise ScenarioError(f"--config {path}: cannot read it ({exc.strerror})") from None
    except (msgspec.DecodeError, msgspec.ValidationError) as exc:
        raise ScenarioError(f"--config {path}: not {what}: {exc}") from None
