"""The compiled per-vehicle core: which modules mypyc compiles, and whether this process runs them.

``setup.py`` compiles the modules in ``MODULES`` with mypyc (C extensions built from the unchanged, mypy-checked
source) when the package is installed (``pip install -e .``, as ``dev.py`` does) and a C compiler is there;
the extensions land beside the ``.py`` files. Python would import such an extension instead of its source,
so every harness process decides here, when ``harness`` is imported, which of the two it runs:

- ``HARNESS_PURE=1`` in the environment: the sources (plain Python);
- no build (no ``MANIFEST``: no compiler, or never built): the sources, silently;
- a build whose recorded source digests differ from the sources now (a ``.py`` edited after the build): the
  sources, with one warning naming the changed modules (rebuild: ``pip install -e .`` or
  ``python setup.py build_ext --inplace``). A stale extension would silently run the old code;
- otherwise the compiled modules (``ACTIVE``).

It is all or nothing: compiled modules call each other directly (one shared library), so one stale module
makes the whole build stale. Refusing an extension is a finder at the front of ``sys.meta_path`` that gives
harness module names their source files (all but ``MODULES`` when the build is in use: an extension left
by an earlier build of a module since dropped from ``MODULES`` is never imported).

Both run the same IEEE double arithmetic in the order written (the C code is built with
``-ffp-contract=off``: no fused multiply-add), and the same libm: the same inputs give the same bits
(``benchmarks/truth_digest.py``). numba's kernels (``harness.core.jit``) are plain functions where compiled by
mypyc, so ``jit`` does not compile them when ``ACTIVE``.

This module is imported by ``harness/__init__.py`` and by ``setup.py`` (by path, before the package is
installed): it imports nothing from harness.
"""

from __future__ import annotations

import hashlib
import importlib.abc
import importlib.machinery
import importlib.util
import json
import logging
import os
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import ModuleType

MODULES: tuple[str, ...] = (
    "harness.core.geo",
    "harness.autopilot.mathutil",
    "harness.autopilot.battery",
    "harness.autopilot.inner",
    "harness.autopilot.control",
    "harness.autopilot.estimator",
    "harness.autopilot.navigator",
    "harness.autopilot.supervisor",
    "harness.autopilot.trajectory",
    "harness.autopilot.flight",
    "harness.autopilot.manual",
    "harness.autopilot.snapshot",
    "harness.autopilot.autopilot",
    "harness.fdm.imu",
    "harness.fdm.sensors",
    "harness.fdm.physics",
)
"""The compiled modules: the autopilot's per-tick path (the flight core: cascade, estimator, navigator and its
trajectories, supervisor, battery; the manual-control and state-snapshot stages and ``Autopilot.step``
around them), the sensor model and the physics wrapper around JSBSim, and the quaternion/geodesy helpers
they all call. Each must stay mypyc-compatible: no monkey-patching of its classes or
functions, attributes declared."""

GROUP = "harness._native"
"""mypyc's group: one shared library, ``harness/_native__mypyc.*.so``, and a small extension per module."""

PACKAGE_DIR = Path(__file__).resolve().parents[1]
MANIFEST = PACKAGE_DIR / "_native.json"
"""Written by the build: ``{"modules": {name: sha256 of its source}}`` for the modules it compiled."""

_log = logging.getLogger(__name__)


def source_of(module: str, package_dir: Path = PACKAGE_DIR) -> Path:
    return package_dir.joinpath(*module.split(".")[1:]).with_suffix(".py")


def digests(package_dir: Path = PACKAGE_DIR) -> dict[str, str]:
    """The sha256 of each compiled module's source now."""
    return {m: hashlib.sha256(source_of(m, package_dir).read_bytes()).hexdigest() for m in MODULES}


def decide(
    environ: Mapping[str, str] = os.environ, manifest: Path = MANIFEST, package_dir: Path = PACKAGE_DIR
) -> tuple[bool, str]:
    """(whether the compiled modules run, why): see the module docstring."""
    if environ.get("HARNESS_PURE", "0") not in ("", "0"):
        return False, "HARNESS_PURE is set"
    try:
        built = json.loads(manifest.read_text())["modules"]
    except (OSError, ValueError, KeyError, TypeError):
        return False, "not built"
    now = digests(package_dir)
    stale = sorted(m for m in MODULES if built.get(m) != now[m])
    if stale:
        _log.warning(
            "harness: the compiled modules are stale (%s changed since the build): running pure Python; "
            "rebuild with `pip install -e .` or `python setup.py build_ext --inplace`",
            ", ".join(stale),
        )
        return False, "stale: " + ", ".join(stale)
    return True, "built"


class _Sources(importlib.abc.MetaPathFinder):
    """Gives every harness module that has a ``.py`` its source, so that an extension beside it is not
    imported, except the compiled modules of a build in use (``ACTIVE``). That covers the extension left
    behind by an earlier build of a module no longer in ``MODULES`` too (it would load the old code, or fail
    against the new shared library)."""

    def find_spec(
        self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        if not path or not fullname.startswith("harness.") or (ACTIVE and fullname in _NAMES):
            return None
        for folder in path:
            src = os.path.join(folder, fullname.rpartition(".")[2] + ".py")
            if os.path.isfile(src):
                return importlib.util.spec_from_file_location(fullname, src)
        return None


_NAMES = frozenset(MODULES)
ACTIVE, REASON = decide()
"""Whether this process runs the compiled modules, and why (or why not)."""


def install() -> None:
    """Called once by ``harness/__init__.py``: every harness module is imported from its source but the
    compiled ``MODULES`` when ``ACTIVE``."""
    if not any(isinstance(f, _Sources) for f in sys.meta_path):
        sys.meta_path.insert(0, _Sources())


def loaded() -> dict[str, bool]:
    """For each compiled module imported so far: whether it is the extension (for tests and diagnostics)."""
    return {m: not (getattr(sys.modules[m], "__file__", "") or "").endswith(".py") for m in MODULES if m in sys.modules}
