"""Compiling the per-vehicle-tick arithmetic: ``kernel`` is numba's ``njit`` with an on-disk cache.

The control cascade, the estimator's prediction and the IMU model run for every vehicle at every 250 Hz tick;
in plain Python their float arithmetic cost more than JSBSim's own step. Their equations are written once,
as plain functions of floats (and of small float64 arrays that hold a controller's state or gains, mutated
in place), and compiled to machine code by numba. A call from Python costs about 20 ns per float argument
and 90 ns per array, so a stage is one call, not one per formula.

Compiled code is IEEE double arithmetic in the order written (no ``fastmath``: no reassociation, no fused
multiply-add), so the same inputs give the same bits, in every process.

``cache=True``: the machine code is written beside the source (``__pycache__/*.nbi, *.nbc``) the first time a
kernel is called on a machine and loaded from there afterwards; numba writes the files atomically, so
processes compiling at once do not break each other. Where that directory is not writable numba uses its
user-wide cache directory (``NUMBA_CACHE_DIR`` if set); where neither is, ``kernel`` falls back to a
directory under the system's temporary directory, and failing that compiles in memory (every process then
compiles afresh, a second or two of start-up, and logs a warning).

Only the modules that step autopilots or sensors import this one: ``import numba`` costs about 0.2 s.
"""

from __future__ import annotations

import logging
import os
import tempfile
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba
from numba.core import config as numba_config

F = TypeVar("F", bound=Callable[..., Any])

_log = logging.getLogger(__name__)


def _fallback_cache_dir() -> str:
    return os.path.join(tempfile.gettempdir(), f"harness-numba-cache-{os.getuid()}")


def kernel(fn: F) -> F:
    """``fn`` compiled by numba in nopython mode with the on-disk cache (see the module docstring)."""
    try:
        return cast(F, numba.njit(cache=True)(fn))
    except RuntimeError:
        # "cannot cache function ...: no locator available": neither the source tree nor the user-wide cache
        # directory is writable
        pass
    if not getattr(numba_config, "CACHE_DIR", ""):
        setattr(numba_config, "CACHE_DIR", _fallback_cache_dir())  # noqa: B010  (numba's config is untyped)
        try:
            return cast(F, numba.njit(cache=True)(fn))
        except RuntimeError:
            pass
    _log.warning("numba: no writable cache directory for %s; compiling it in memory", fn.__qualname__)
    return cast(F, numba.njit(fn))
