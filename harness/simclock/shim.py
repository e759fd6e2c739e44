"""The sim-time shims' shared objects: where they are, and compiling them (``simtime.c`` → ``simtime-<hash>.so``,
the mission's side; ``simchild.c`` → ``simchild-<hash>.so``, its child processes' side).

They are compiled when the package is built (``setup.py`` loads this module by path and puts the shared objects in
the wheel beside their sources) and, where a build has none (no C compiler when it was built, or a source edited
since), with the machine's C compiler the first time a mission needs them (about 0.3 s each), into the user's
cache directory. Both are named by the source's hash, so a build of another source is never loaded. Without
either, MAVSDK's threads (and the mission's C-level waits and children) keep the wall clock: one warning says so.

This module imports nothing from harness (``setup.py`` loads it before the package is installed).
"""

from __future__ import annotations

import fcntl
import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

log = logging.getLogger(__name__)

SOURCE = Path(__file__).with_name("simtime.c")
"""The mission's side: its own threads' and libraries' clock reads and waits (``docs/simclock.md``)."""
CHILD_SOURCE = Path(__file__).with_name("simchild.c")
"""The child processes' side (``LD_PRELOAD`` in programs a mission starts; the GOTs of a process it forks)."""
SOURCES = (SOURCE, CHILD_SOURCE)
_warned = False


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "uav-harness"


def compiler() -> str | None:
    """The C compiler: ``$CC``, else ``cc``, ``gcc`` or ``clang`` on PATH."""
    cc = os.environ.get("CC")
    if cc and shutil.which(cc.split()[0]):
        return cc
    for name in ("cc", "gcc", "clang"):
        if shutil.which(name):
            return name
    return None


def shim_name(source: Path = SOURCE) -> str:
    """The compiled shim's file name: ``<stem>-<sha256 of the source, 16 hex>.so`` (a build of another source
    is never loaded)."""
    return f"{source.stem}-{hashlib.sha256(source.read_bytes()).hexdigest()[:16]}.so"


def packaged_path(source: Path = SOURCE) -> Path:
    """Where a build of the package put the shim (``setup.py``): beside its source."""
    return source.with_name(shim_name(source))


def library_path(source: Path = SOURCE) -> Path:
    """Where the shim is compiled at run time when the package has none: the user's cache."""
    return cache_dir() / shim_name(source)


def compile_shim(target: Path, source: Path = SOURCE) -> str | None:
    """Compile ``source`` into ``target`` (atomically: written beside it, then renamed); None when it worked,
    else why not (one line)."""
    cc = compiler()
    if cc is None:
        return "no C compiler (cc, gcc or clang)"
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=".so", dir=target.parent)
    os.close(fd)
    cmd = [*cc.split(), "-O2", "-shared", "-fPIC", "-o", tmp, str(source), "-ldl", "-lpthread"]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        os.unlink(tmp)
        last = proc.stderr.strip().splitlines()[-1:]
        return f"building {source.name} failed ({last[0] if last else f'exit {proc.returncode}'})"
    os.chmod(tmp, 0o755)
    os.replace(tmp, target)
    return None


def build(source: Path = SOURCE) -> Path | None:
    """The compiled shim: the package's own, else the user cache's (:func:`cached`); None without a C compiler or
    when the build fails (one warning per process)."""
    packaged = packaged_path(source)
    return packaged if packaged.is_file() else cached(source)


def cached(source: Path = SOURCE) -> Path | None:
    """The shim in the user's cache, compiled there if needed (once, however many processes ask at once)."""
    global _warned
    target = library_path(source)
    if target.is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    with open(target.parent / ".simtime.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # a hundred missions may ask at once: one compiles
        if target.is_file():
            return target
        why = compile_shim(target, source)
    if why is not None:
        if not _warned:
            _warned = True
            log.warning("%s: MAVSDK's own threads and the mission's C-level waits stay on the wall clock", why)
        return None
    return target
