"""Parameter storage per vehicle that survives a restart of the vehicle within a run directory.

Every change (PARAM_SET from a ground station or ``set_param`` in-process) rewrites
``<run_dir>/params/vehicle-<i>.json`` with the values that differ from their defaults (atomically: a
temporary file then ``os.replace``). A vehicle started again in the same run directory gets them back::

    refused = persist_params(autopilot.params, run_dir, vehicle)   # restore, then keep saving
"""

from __future__ import annotations

import json
import logging
import math
import os
import threading
from pathlib import Path

from harness.autopilot.params import Params
from harness.autopilot.services import System
from harness.core.limits import cut, shown

log = logging.getLogger(__name__)

MAX_FILE_BYTES = 1 << 20
"""A saved parameter file holds a few hundred names and numbers: one larger is not ours."""
_NAME_MAX = 64


def _finite(value: object) -> float | None:
    """``value`` as a float when it is a finite number (not a bool, not an int too large for a float)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) else None


def run_dir_of(system: System) -> Path | None:
    """The run directory of a vehicle whose run writes files (where its ULog is), or None."""
    logs = system.log_files.files() if system.log_files is not None else []
    return logs[0][0].parent if logs else None


def store_path(run_dir: Path, vehicle: int, firmware: str = "") -> Path:
    """The core's parameters: ``vehicle-<i>.json``; a personality's own table: ``vehicle-<i>-<firmware>.json``."""
    return run_dir / "params" / (f"vehicle-{vehicle}-{firmware}.json" if firmware else f"vehicle-{vehicle}.json")


class ParamStore:
    def __init__(self, path: Path) -> None:
        self.path = path
        self._lock = threading.Lock()

    def load(self) -> dict[str, float]:
        """The saved values ({} when nothing was saved). The file may have been written by anyone (a ground
        station over MAVFTP): one too big, not JSON, nested or not an object is ignored, and so is every value
        that is not a finite number a float holds — each said in one warning line, never an exception that
        would stop a reboot or the next start on this run directory."""
        try:
            with self.path.open("rb") as f:
                data = f.read(MAX_FILE_BYTES + 1)
        except FileNotFoundError:
            return {}
        except OSError as e:
            log.warning("ignoring unreadable parameter file %s: %s", self.path, e)
            return {}
        if len(data) > MAX_FILE_BYTES:
            log.warning("ignoring parameter file %s: larger than %d bytes", self.path, MAX_FILE_BYTES)
            return {}
        try:
            parsed = json.loads(data)  # NaN and Infinity parse, and are ignored below as any non-finite value
        except (ValueError, RecursionError) as e:
            log.warning("ignoring unreadable parameter file %s: %s", self.path, cut(str(e), 200))
            return {}
        if not isinstance(parsed, dict):
            log.warning("ignoring parameter file %s: not a JSON object", self.path)
            return {}
        values: dict[str, float] = {}
        refused: list[str] = []
        for name, v in parsed.items():
            number = _finite(v)
            if number is None or len(name) > _NAME_MAX:
                refused.append(shown(name, 20))
            else:
                values[name] = number
        if refused:
            log.warning(
                "parameter file %s: %d value(s) ignored, not finite numbers: %s",
                self.path, len(refused), cut(", ".join(refused), 200),
            )  # fmt: skip
        return values

    def save(self, params: Params) -> None:
        defaults = {d.name: d.default for d in params.defs}
        changed = {k: v for k, v in params.snapshot().items() if v != defaults[k]}
        with self._lock:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.path.with_suffix(".tmp")
            tmp.write_text(json.dumps(changed, indent=1, sort_keys=True))
            os.replace(tmp, self.path)


def persist_params(params: Params, run_dir: Path, vehicle: int, firmware: str = "") -> list[str]:
    """Restore the vehicle's saved parameters into ``params`` and save every later change (``firmware``: the
    file of a personality's own table, e.g. ArduCopter's names, beside the core's).

    Returns the reasons of saved values that were refused (e.g. a range that changed since)."""
    store = ParamStore(store_path(run_dir, vehicle, firmware))
    refused = params.update(store.load())
    for reason in refused:
        log.warning("vehicle %d: saved parameter not restored: %s", vehicle, reason)

    def on_change(_name: str, _value: float) -> None:
        try:
            store.save(params)
        except OSError as e:
            log.warning("vehicle %d: cannot save parameters to %s: %s", vehicle, store.path, e)

    params.subscribe(on_change)
    return refused


def reload_params(params: Params, run_dir: Path | None, vehicle: int) -> list[str]:
    """Parameters as a vehicle starting now would have them: defaults, the run's overrides (``params.overrides``),
    then the saved file (which a ground station may have replaced, e.g. over MAVFTP). Returns the reasons of
    values refused."""
    saved = ParamStore(store_path(run_dir, vehicle)).load() if run_dir is not None else {}
    target = {d.name: d.default for d in params.defs} | params.overrides | saved
    return params.update({n: v for n, v in target.items() if n in params and params[n] != v})
