"""Compiling the per-vehicle-tick arithmetic: ``kernel`` is numba's ``njit`` with an on-disk cache.

The control cascade, the estimator's prediction and the IMU model run for every vehicle at every 250 Hz tick;
in plain Python their float arithmetic cost more than JSBSim's own step. Their equations are written once,
as plain functions of floats (and of small float64 arrays that hold a controller's state or gains, mutated
in place), and compiled to machine code by numba for the argument types their annotations give. Through
numba's dispatcher a call costs about 20 ns per float argument and 90 ns per array, so a stage is one call,
not one per formula; the hot paths call the compiled entry point (``compiled``), which skips that typing.

Compiled code is IEEE double arithmetic in the order written (no ``fastmath``: no reassociation, no fused
multiply-add), so the same inputs give the same bits, in every process.

``cache=True``: the machine code is written beside the source (``__pycache__/*.nbi, *.nbc``) the first time a
kernel's module is imported on a machine and loaded from there afterwards; numba writes the files atomically, so
processes compiling at once do not break each other. Where that directory is not writable numba uses its
user-wide cache directory (``NUMBA_CACHE_DIR`` if set); where neither is, ``kernel`` falls back to a
directory under the system's temporary directory, and failing that compiles in memory (every process then
compiles afresh, a second or two of start-up, and logs a warning).

numba checks only the kernel's own source file for changes: every kernel a kernel calls must be in the same
module, and a constant imported from elsewhere is frozen into the cached code (clear ``__pycache__/*.nb*``
after changing one).

Only the modules that step autopilots or sensors import this one: ``import numba`` and loading the kernels
cost a few tenths of a second of CPU per process.

Where mypyc's compiled core runs (``harness.core.native``) the kernels' modules are C extensions and numba is
not used, whatever ``HARNESS_JIT`` says.

``HARNESS_JIT=0`` in the environment: numba is not imported and the kernels run as the plain Python functions
they are, over lists instead of arrays (``floats``), with the same results to the bit. For a process that
steps a single vehicle for a short flight that is cheaper than numba's start-up.
"""

from __future__ import annotations

import inspect
import logging
import os
import tempfile
from collections.abc import Callable
from typing import Any, TypeAlias, TypeVar, cast

import numpy as np

from harness.core import native

F = TypeVar("F", bound=Callable[..., Any])

Floats: TypeAlias = list[float]
"""The type of a kernel's state or gains parameter (``floats``): numba compiles it as a float64 array, mypy and
mypyc (``harness.core.native``) see the list of floats it is where kernels are not numba-compiled, so that
mypyc's code indexes a list and does C double arithmetic instead of generic object arithmetic."""

ENABLED = os.environ.get("HARNESS_JIT", "1") != "0" and not native.ACTIVE
"""Whether kernels are compiled (``HARNESS_JIT``, read at import; ``prefer`` may change it before any kernel).
Never when the compiled core runs (``harness.core.native.ACTIVE``): mypyc has compiled the kernels' modules,
their functions are machine code already (and numba cannot read them)."""

_made = False


def prefer(compiled: bool) -> bool:
    """Compile the kernels or not, unless ``HARNESS_JIT`` says or a kernel was already made (the choice must
    hold for all of a process's kernels and their state arrays). Returns whether kernels are compiled.

    numba's start-up (≈ 0.4 s of CPU) pays back from about two vehicles in a process; a process stepping one
    vehicle prefers plain Python."""
    global ENABLED
    if "HARNESS_JIT" not in os.environ and not _made and not native.ACTIVE:
        ENABLED = compiled
    return ENABLED


_log = logging.getLogger(__name__)


def _fallback_cache_dir() -> str:
    return os.path.join(tempfile.gettempdir(), f"harness-numba-cache-{os.getuid()}")


def floats(values: Any) -> Any:
    """A kernel's state or gains: a float64 array when kernels are compiled, a list of floats when they run as
    Python (indexing a list is fast in Python, an array's element slow)."""
    _made_one()
    return np.array(values, dtype=np.float64) if ENABLED else [float(v) for v in values]


def _signature(fn: Callable[..., Any]) -> tuple[Any, ...]:
    """The argument types of ``fn`` from its annotations (the return type numba infers)."""
    import numba

    # the numba type of each annotation a kernel's parameter may have (arrays: float64, 1-D, C-contiguous)
    by_name = {
        "float": numba.float64,
        "bool": numba.boolean,
        "int": numba.int64,
        "np.ndarray": numba.float64[::1],
        "Floats": numba.float64[::1],
    }
    types = []
    for p in inspect.signature(fn, eval_str=False).parameters.values():
        t = by_name.get(str(p.annotation))
        if t is None:
            raise TypeError(f"kernel {fn.__qualname__}: parameter {p.name} is {p.annotation!r}; use {list(by_name)}")
        types.append(t)
    return tuple(types)


def _njit(fn: F, sig: tuple[Any, ...] | None) -> F:
    """numba's njit with the on-disk cache, falling back as the module docstring says."""
    import numba
    from numba.core import config as numba_config

    try:
        return cast(F, numba.njit(sig, cache=True)(fn))
    except RuntimeError:
        # "cannot cache function ...: no locator available": neither the source tree nor the user-wide cache
        # directory is writable
        pass
    if not getattr(numba_config, "CACHE_DIR", ""):
        setattr(numba_config, "CACHE_DIR", _fallback_cache_dir())  # noqa: B010  (numba's config is untyped)
        try:
            return cast(F, numba.njit(sig, cache=True)(fn))
        except RuntimeError:
            pass
    _log.warning("numba: no writable cache directory for %s; compiling it in memory", fn.__qualname__)
    return cast(F, numba.njit(sig)(fn))


def _made_one() -> None:
    global _made
    _made = True


def kernel(fn: F) -> F:
    """``fn`` compiled by numba in nopython mode for the argument types its annotations give, with the on-disk
    cache (see the module docstring). Compiled (or loaded from the cache) here, at import: one signature, so
    nothing compiles later in a run; arguments of other types are converted or refused (TypeError).
    ``fn`` itself when kernels are not compiled (``ENABLED``)."""
    _made_one()
    return _njit(fn, _signature(fn)) if ENABLED else fn


def callee(fn: F) -> F:
    """``fn`` compiled by numba, lazily: for a function that kernels call (compiled into them, at their types)
    and Python calls only off the hot path (tests, single stages). Loading it at import would cost a few
    milliseconds for code the kernels already contain."""
    _made_one()
    if not ENABLED:
        return fn
    _signature(fn)  # the same annotations as a kernel's
    return _njit(fn, None)


def compiled(k: F) -> F:
    """The machine-code entry point of kernel ``k`` (its one signature), for calls from Python on the hot path:
    it skips numba's dispatch, which types every argument on every call (≈ 25 ns each; a 29-argument kernel
    is called in half the time). It converts floats and bools as the dispatcher does but does not check an
    array's dtype or layout: pass only the float64 arrays the kernel's owner made (``floats``). ``k`` itself
    when kernels are not compiled."""
    if not ENABLED:
        return k
    disp = cast(Any, k)
    (sig,) = disp.signatures
    return cast(F, disp.overloads[sig].entry_point)
