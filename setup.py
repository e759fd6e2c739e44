"""Build hook beside pyproject.toml: the per-vehicle core compiled to C extensions by mypyc, the sim-time shims
for C libraries and child processes (``harness/simclock/simtime*.c``, ``simchild.c``) compiled into the package,
and the example missions (``missions/``) packaged as ``harness.examples``.

The modules are ``harness.core.native.MODULES`` (read here by path: the package is not installed yet). They
are compiled when the package is built or installed (``pip install -e .``, as ``dev.py`` does; in place:
``python setup.py build_ext --inplace``) and a C compiler is found; the build then writes
``harness/_native.json`` with the sha256 of each source it compiled, which ``harness.core.native`` checks at
import (a source edited since the build runs as Python, with a warning). With no compiler, or
``HARNESS_PURE=1`` at build time, or a failed compile, the install still succeeds, pure Python, and says so
once.

The shims are plain shared objects (loaded with ctypes or LD_PRELOAD, not imported), named by the hash of their
sources and headers (``harness.simclock.shim``); they are built whatever ``HARNESS_PURE`` says (they put MAVSDK's threads, a
mission's C-level waits and its children on the sim clock; they are not the per-vehicle core). Without a compiler
the package still installs: the shims are then compiled at run time into the user's cache where a compiler
exists, else those keep the wall clock.
"""

from __future__ import annotations

import functools
import importlib.machinery
import importlib.util
import json
import logging
import os
import shlex
import shutil
import sys
import sysconfig
from pathlib import Path
from typing import Any

from setuptools import Extension, find_packages, setup
from setuptools.command.build_ext import build_ext

ROOT = Path(__file__).resolve().parent


def _by_path(name: str, path: Path) -> Any:
    """A module of harness that imports nothing from harness, loaded by path (the package is not installed)."""
    logging.getLogger(name).setLevel(logging.ERROR)  # a stale build is what we are about to replace
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


NATIVE = _by_path("_harness_native", ROOT / "harness" / "core" / "native.py")
SHIM = _by_path("_harness_shim", ROOT / "harness" / "simclock" / "shim.py")


def _say(message: str) -> None:
    print(f"uav-harness: {message}", file=sys.stderr, flush=True)


def _compiler() -> str | None:
    """The C compiler Python's build would call, if it is there."""
    cc = os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc"
    exe = shlex.split(cc)[0] if cc.strip() else "cc"
    return shutil.which(exe)


@functools.cache  # setuptools sets up build_ext more than once per build: mypyc runs (and this speaks) once
def _extensions() -> list[Any]:
    if os.environ.get("HARNESS_PURE", "0") not in ("", "0"):
        _say("HARNESS_PURE is set: the per-vehicle core is not compiled (pure Python)")
        return []
    if _compiler() is None:
        _say("no C compiler found: the per-vehicle core is not compiled (pure Python, same results, slower)")
        return []
    try:
        from mypyc.build import mypycify
    except ImportError:
        _say("mypyc is not installed: the per-vehicle core is not compiled (pure Python)")
        return []
    old = Path.cwd()
    os.chdir(ROOT)  # mypyc reads pyproject.toml's [tool.mypy] and names modules by path from here
    try:
        paths = [str(NATIVE.source_of(m, Path("harness"))) for m in NATIVE.MODULES]
        exts = mypycify(paths, opt_level="3", group_name=NATIVE.GROUP)
    finally:
        os.chdir(old)
    for ext in exts:
        # IEEE double arithmetic in the order written, as Python's: no fused multiply-add (whatever CFLAGS say)
        ext.extra_compile_args = [*ext.extra_compile_args, "-ffp-contract=off", "-fno-fast-math"]
    return list(exts)


def _drop_leftovers() -> None:
    """Delete the in-place extensions of modules an earlier build compiled and this one does not (harness would
    not import them, but they would confuse whoever lists the tree)."""
    keep = {*NATIVE.MODULES, f"{NATIVE.GROUP}__mypyc"}
    suffixes = tuple(importlib.machinery.EXTENSION_SUFFIXES)
    for path in (ROOT / "harness").rglob("*"):
        if path.name.startswith(tuple(f"{shim.stem}-" for shim in SHIM.SHIMS)):
            continue  # a sim-time shim (not a Python module): _build_shim keeps the current one only
        if path.name.endswith(suffixes):
            name = path.name[: -len(next(s for s in suffixes if path.name.endswith(s)))]
            module = ".".join((*path.relative_to(ROOT).parent.parts, name))
            if module not in keep:
                path.unlink()
                _say(f"removed {path.relative_to(ROOT)}: no longer compiled")


class BuildNative(build_ext):
    """build_ext that runs mypyc (when the command is set up, not when setup.py is loaded: pip loads it three
    times per install),
    records what it compiled (``harness/_native.json``) and falls back to pure Python when the compile fails."""

    def finalize_options(self) -> None:
        self.distribution.ext_modules = list(_extensions())
        super().finalize_options()

    _shims: list[Path]

    def run(self) -> None:
        self._shims = []
        self._build_shim()
        if not self.extensions:
            return
        try:
            super().run()
        except Exception as e:  # a compiler that is there but fails: install the pure-Python package
            _say(f"compiling the per-vehicle core failed ({e}): pure Python")
            self._manifest().unlink(missing_ok=True)
            return
        if self.inplace or getattr(self, "editable_mode", False):
            _drop_leftovers()
        manifest = self._manifest()
        manifest.parent.mkdir(parents=True, exist_ok=True)
        manifest.write_text(json.dumps({"modules": NATIVE.digests(ROOT / "harness")}, indent=1, sort_keys=True))
        _say(f"compiled the per-vehicle core with mypyc: {len(NATIVE.MODULES)} modules")

    def _inplace(self) -> bool:
        return bool(self.inplace or getattr(self, "editable_mode", False))

    def _manifest(self) -> Path:
        return NATIVE.MANIFEST if self._inplace() else Path(self.build_lib) / "harness" / NATIVE.MANIFEST.name

    def _build_shim(self) -> None:
        """The sim-time shims (``simtime*.c``, ``simchild.c``) compiled beside their sources in the package
        (``<stem>-<hash>.so``); a failure is one line."""
        folder = SHIM.FOLDER if self._inplace() else Path(self.build_lib) / "harness" / "simclock"
        for shim in SHIM.SHIMS:
            target = folder / SHIM.shim_name(shim)
            for old in folder.glob(f"{shim.stem}-*.so"):
                if old != target:
                    old.unlink()  # a build of earlier sources: never loaded, removed
            why = None if target.is_file() else SHIM.compile_shim(target, shim)
            if why is None:
                self._shims.append(target)
                _say(f"built the sim-time shim {target.name}")
            else:
                _say(f"{why}: {shim.stem} is not built into the package (built at run time if a compiler is there)")

    def get_outputs(self) -> list[str]:
        outputs = [*super().get_outputs(), str(self._manifest())] if self.extensions else super().get_outputs()
        return [*outputs, *map(str, getattr(self, "_shims", []))]


# A stand-in until build_ext runs mypyc: the package has extension modules (a platform wheel, build_ext runs).
# The example missions live in missions/ (where users of a checkout find them) and install as harness.examples.
setup(
    packages=[*find_packages(include=["harness", "harness.*"]), "harness.examples"],
    package_dir={"harness.examples": "missions"},
    ext_modules=[Extension(f"{NATIVE.GROUP}__mypyc", sources=[])],
    cmdclass={"build_ext": BuildNative},
)
