"""Parameter storage per vehicle that survives a restart of the vehicle within a run directory.

Every change (PARAM_SET from a ground station or ``set_param`` in-process) rewrites
``<run_dir>/params/vehicle-<i>.json`` with the values that differ from their defaults (atomically: a
temporary file then ``os.replace``). A vehicle started again in the same run directory gets them back::

    refused = persist_params(autopilot.params, run_dir, vehicle)   # restore, then keep saving
"""

from __future__ import annotations

import json
import logging
import os
import threading
from pathlib import Path

from harness.autopilot.params import Params
from harness.autopilot.services import System

log = logging.getLogger(__name__)


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
        """The saved values ({} when nothing was saved; a corrupt file is logged and ignored)."""
        try:
            data = json.loads(self.path.read_text())
        except FileNotFoundError:
            return {}
        except (OSError, ValueError) as e:
            log.warning("ignoring unreadable parameter file %s: %s", self.path, e)
            return {}
        if not isinstance(data, dict):
            log.warning("ignoring parameter file %s: not a JSON object", self.path)
            return {}
        return {str(k): float(v) for k, v in data.items() if isinstance(v, int | float)}

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
