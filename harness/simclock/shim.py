"""The sim-time shims' shared objects: what each is built from, where they are, and compiling them (``simtime.c``
and its parts ``simtime_*.c`` → ``simtime-<hash>.so``, the mission's side; ``simchild.c`` → ``simchild-<hash>.so``,
its child processes' side; both include ``simcommon.h``).

They are compiled when the package is built (``setup.py`` loads this module by path and puts the shared objects in
the wheel beside their sources) and, where a build has none (no C compiler when it was built, or a source edited
since), with the machine's C compiler the first time a mission needs them (about 0.3 s each), into the user's
cache directory. Each is named by the hash of every file it is built from (its sources and the headers they
include), so a build of other sources is never loaded. Without either, MAVSDK's threads (and the mission's C-level
waits and children) keep the wall clock: one warning says so.

This module imports nothing from harness (``setup.py`` loads it before the package is installed).
"""

from __future__ import annotations

import fcntl
import hashlib
import logging
import os
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)

FOLDER = Path(__file__).parent
"""Where the shims' sources are, and where a build of the package puts their shared objects."""
_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.MULTILINE)


@dataclass(frozen=True)
class Shim:
    """One shared object: the C sources compiled into it (with the headers they include, ``#include "…"``)."""

    stem: str
    """The shared object's name before its hash: ``<stem>-<hash16>.so``."""
    sources: tuple[str, ...]
    """The C files compiled, in ``FOLDER``."""
    cflags: tuple[str, ...] = ()

    def source_paths(self) -> tuple[Path, ...]:
        return tuple(FOLDER / name for name in self.sources)

    def files(self) -> tuple[Path, ...]:
        """Every file the build reads: the sources and the headers they include, transitively (sorted by name)."""
        seen: dict[str, Path] = {}
        todo = list(self.source_paths())
        while todo:
            path = todo.pop()
            if path.name in seen:
                continue
            seen[path.name] = path
            todo.extend(path.with_name(name) for name in _INCLUDE.findall(path.read_text()))
        return tuple(seen[name] for name in sorted(seen))


MISSION = Shim(
    "simtime",
    ("simtime.c", "simtime_clock.c", "simtime_io.c", "simtime_children.c", "simtime_control.c", "simtime_patch.c"),
    ("-fvisibility=hidden",),  # exported: the hs_* functions simtime.h marks HS_API, which native.py calls
)
"""The mission's side: its own threads' and libraries' clock reads and waits (``docs/simclock.md``)."""
CHILD = Shim("simchild", ("simchild.c",))
"""The child processes' side (``LD_PRELOAD`` in programs a mission starts; the GOTs of a process it forks): it
exports libc's own names, so its symbols keep the default visibility."""
SHIMS = (MISSION, CHILD)
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


def shim_name(shim: Shim = MISSION) -> str:
    """The compiled shim's file name: ``<stem>-<sha256 of every file it is built from, 16 hex>.so`` (a build of
    other sources is never loaded; editing ``simcommon.h`` renames both shims)."""
    digest = hashlib.sha256()
    for path in shim.files():
        data = path.read_bytes()
        digest.update(f"{path.name}\0{len(data)}\0".encode())
        digest.update(data)
    return f"{shim.stem}-{digest.hexdigest()[:16]}.so"


def packaged_path(shim: Shim = MISSION) -> Path:
    """Where a build of the package put the shim (``setup.py``): beside its sources."""
    return FOLDER / shim_name(shim)


def library_path(shim: Shim = MISSION) -> Path:
    """Where the shim is compiled at run time when the package has none: the user's cache."""
    return cache_dir() / shim_name(shim)


def compile_shim(target: Path, shim: Shim = MISSION) -> str | None:
    """Compile ``shim`` into ``target`` (atomically: written beside it, then renamed); None when it worked,
    else why not (one line)."""
    cc = compiler()
    if cc is None:
        return "no C compiler (cc, gcc or clang)"
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=".so", dir=target.parent)
    os.close(fd)
    sources = [str(path) for path in shim.source_paths()]
    cmd = [*cc.split(), "-O2", "-shared", "-fPIC", *shim.cflags, "-o", tmp, *sources, "-ldl", "-lpthread"]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        os.unlink(tmp)
        last = proc.stderr.strip().splitlines()[-1:]
        return f"building {shim.stem} failed ({last[0] if last else f'exit {proc.returncode}'})"
    os.chmod(tmp, 0o755)
    os.replace(tmp, target)
    return None


def build(shim: Shim = MISSION) -> Path | None:
    """The compiled shim: the package's own, else the user cache's (:func:`cached`); None without a C compiler or
    when the build fails (one warning per process)."""
    packaged = packaged_path(shim)
    return packaged if packaged.is_file() else cached(shim)


def cached(shim: Shim = MISSION) -> Path | None:
    """The shim in the user's cache, compiled there if needed (once, however many processes ask at once)."""
    global _warned
    target = library_path(shim)
    if target.is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    with open(target.parent / ".simtime.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # a hundred missions may ask at once: one compiles
        if target.is_file():
            return target
        why = compile_shim(target, shim)
    if why is not None:
        if not _warned:
            _warned = True
            log.warning("%s: MAVSDK's own threads and the mission's C-level waits stay on the wall clock", why)
        return None
    return target
