"""Metrics a mission reports for its run: ``report(max_drift_m=0.4, reached=True)``.

The convention (``docs/sweep.md``): a JSON object in ``$HARNESS_RUN_DIR/metrics-$HARNESS_VEHICLE.json``.
``harness sweep`` turns each key into a results.csv column ``v<vehicle>.<key>``. Any script can write the
file itself; this helper merges with what is already there and replaces the file atomically, so a run that
stops half-way never leaves a torn file. Outside a harness run (no ``$HARNESS_RUN_DIR``) it does nothing.
"""

from __future__ import annotations

import json
import logging
import math
import os
from pathlib import Path

log = logging.getLogger(__name__)

Value = float | int | bool | str | None


def metrics_path() -> Path | None:
    """Where this process's metrics go, or None outside a harness run."""
    run_dir = os.environ.get("HARNESS_RUN_DIR")
    if not run_dir:
        return None
    return Path(run_dir) / f"metrics-{int(os.environ.get('HARNESS_VEHICLE', '0'))}.json"


def report(**values: Value) -> Path | None:
    """Add ``values`` to this vehicle's metrics (later calls win per key); returns the file written."""
    for key, value in values.items():
        if not (value is None or isinstance(value, bool | int | float | str)):
            raise TypeError(f"metric {key}: expected a number, bool or string, got {type(value).__name__}")
        if isinstance(value, float) and not math.isfinite(value):
            values[key] = None  # JSON has no NaN/inf: an empty cell
    path = metrics_path()
    if path is None:
        log.info("not in a harness run ($HARNESS_RUN_DIR unset): metrics %s not written", values)
        return None
    current: dict[str, Value] = {}
    if path.is_file():
        try:
            current = dict(json.loads(path.read_text()))
        except ValueError:
            current = {}
    current.update(values)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(current, indent=2))
    os.replace(tmp, path)
    return path
