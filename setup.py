"""Build hook beside pyproject.toml: the per-vehicle core compiled to C extensions by mypyc.

The modules are ``harness.core.native.MODULES`` (read here by path: the package is not installed yet). They
are compiled when the package is built or installed (``pip install -e .``, as ``dev.py`` does; in place:
``python setup.py build_ext --inplace``) and a C compiler is found; the build then writes
``harness/_native.json`` with the sha256 of each source it compiled, which ``harness.core.native`` checks at
import (a source edited since the build runs as Python, with a warning). With no compiler, or
``HARNESS_PURE=1`` at build time, or a failed compile, the install still succeeds, pure Python, and says so
once.
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

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

ROOT = Path(__file__).resolve().parent


def _native() -> Any:
    logging.getLogger("_harness_native").setLevel(logging.ERROR)  # a stale build is what we are about to replace
    spec = importlib.util.spec_from_file_location("_harness_native", ROOT / "harness" / "core" / "native.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


NATIVE = _native()


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

    def run(self) -> None:
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

    def _manifest(self) -> Path:
        inplace = self.inplace or getattr(self, "editable_mode", False)
        return NATIVE.MANIFEST if inplace else Path(self.build_lib) / "harness" / NATIVE.MANIFEST.name

    def get_outputs(self) -> list[str]:
        return [*super().get_outputs(), str(self._manifest())] if self.extensions else super().get_outputs()


# A stand-in until build_ext runs mypyc: the package has extension modules (a platform wheel, build_ext runs)
setup(ext_modules=[Extension(f"{NATIVE.GROUP}__mypyc", sources=[])], cmdclass={"build_ext": BuildNative})
