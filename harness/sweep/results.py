"""One row per run: swept parameters, the run's ``summary.json`` and the metrics its missions reported.

Columns (``docs/sweep.md``):

- ``run`` (the run directory's name), ``seed``, one column per swept dotted path (``wind.north_m_s``);
- ``status``, ``message``, ``sim_time_s``, ``wall_time_s``, ``real_time_factor`` (the summary's names),
  ``faults`` (how many), ``worker`` (where the run ran);
- per vehicle i: ``v<i>.mission_exit_code``, ``v<i>.max_altitude_m``, ``v<i>.final_north_m``,
  ``v<i>.final_east_m``, ``v<i>.final_down_m``, ``v<i>.landed``, ``v<i>.armed``, ``v<i>.crashed``;
- mission metrics: every key of ``$HARNESS_RUN_DIR/metrics-<i>.json`` as ``v<i>.<key>``
  (``harness.metrics.report`` writes that file).
"""

from __future__ import annotations

import csv
import json
import logging
import math
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from harness.record.status import read_summary
from harness.run.result import RunStatus

log = logging.getLogger(__name__)

RUN_FIELDS = ("status", "message", "sim_time_s", "wall_time_s", "real_time_factor")
VEHICLE_FIELDS = ("mission_exit_code", "max_altitude_m", "landed", "armed", "crashed")
_METRICS = re.compile(r"^metrics-(\d+)\.json$")


FINISHED = frozenset({RunStatus.OK, RunStatus.FAILED})
"""A re-run keeps these; interrupted, timed-out and lost runs are run again."""


def row_from_run_dir(run_dir: Path, params: Mapping[str, Any], seed: int) -> dict[str, Any]:
    """The row of a finished run (its ``summary.json``); raises FileNotFoundError when there is none."""
    summary = read_summary(run_dir)  # "running" left by a killed run reads as "killed"
    row: dict[str, Any] = {"run": run_dir.name, "seed": seed, **params}
    for key in RUN_FIELDS:
        row[key] = summary.get(key)
    row["faults"] = len(summary.get("faults") or [])
    for v in summary.get("vehicles") or []:
        i = v["id"]
        for key in VEHICLE_FIELDS:
            row[f"v{i}.{key}"] = v.get(key)
        n, e, d = v.get("final_position_ned_m") or (None, None, None)
        row[f"v{i}.final_north_m"], row[f"v{i}.final_east_m"], row[f"v{i}.final_down_m"] = n, e, d
    row.update(read_metrics(run_dir))
    return row


def read_metrics(run_dir: Path) -> dict[str, Any]:
    """``metrics-<i>.json`` files of a run → ``{"v<i>.<key>": value}``; a broken file is logged and skipped."""
    out: dict[str, Any] = {}
    for path in sorted(run_dir.glob("metrics-*.json")):
        m = _METRICS.match(path.name)
        if m is None:
            continue
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            log.warning("%s: not readable as JSON (%s); its metrics are left out", path, exc)
            continue
        if not isinstance(data, dict):
            log.warning("%s: expected a JSON object of metrics, got %s; left out", path, type(data).__name__)
            continue
        for key, value in data.items():
            if isinstance(value, list | dict):
                value = json.dumps(value)
            out[f"v{m.group(1)}.{key}"] = value
    return out


def columns(rows: Iterable[Mapping[str, Any]], params: Iterable[str]) -> list[str]:
    """Every column that any row has, in a fixed order: run, seed, parameters, run fields, vehicles, metrics."""
    rows = list(rows)
    first = ["run", "seed", *params, *RUN_FIELDS, "faults", "worker"]
    seen = {k for r in rows for k in r}
    rest = sorted((k for k in seen if k not in first), key=_vehicle_order)
    return first + rest


def _vehicle_order(key: str) -> tuple[int, int, str]:
    m = re.match(r"^v(\d+)\.(.*)$", key)
    if m is None:
        return (-1, 0, key)
    field = m.group(2)
    builtin = [*VEHICLE_FIELDS[:2], "final_north_m", "final_east_m", "final_down_m", *VEHICLE_FIELDS[2:]]
    return (int(m.group(1)), builtin.index(field) if field in builtin else len(builtin), field)


def write_results(out_dir: Path, rows: list[dict[str, Any]], params: list[str]) -> list[Path]:
    """``results.csv`` (and ``results.parquet`` when pyarrow is installed), written atomically."""
    cols = columns(rows, params)
    written = []
    tmp = out_dir / "results.csv.tmp"
    with tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: _cell(r.get(k)) for k in cols})
    tmp.replace(out_dir / "results.csv")
    written.append(out_dir / "results.csv")
    parquet = _write_parquet(out_dir, rows, cols)
    if parquet is not None:
        written.append(parquet)
    return written


def _cell(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, list | dict):
        return json.dumps(value)
    return value


def _write_parquet(out_dir: Path, rows: list[dict[str, Any]], cols: list[str]) -> Path | None:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return None
    data: dict[str, list[Any]] = {}
    for c in cols:
        values = [r.get(c) for r in rows]
        kinds = {_kind(v) for v in values if v is not None}
        if kinds == {"int", "float"}:
            values = [None if v is None else float(v) for v in values]
        elif len(kinds) > 1 or kinds == {"other"}:
            values = [None if v is None else (v if isinstance(v, str) else json.dumps(v)) for v in values]
        data[c] = values
    tmp = out_dir / "results.parquet.tmp"
    pq.write_table(pa.table(data), tmp)
    tmp.replace(out_dir / "results.parquet")
    return out_dir / "results.parquet"


def _kind(v: Any) -> str:
    if isinstance(v, bool):
        return "bool"
    if isinstance(v, int):
        return "int"
    if isinstance(v, float):
        return "float"
    if isinstance(v, str):
        return "str"
    return "other"


def read_results(path: Path) -> list[dict[str, Any]]:
    """``results.csv`` back as typed rows: numbers, ``True``/``False``, ``None`` for empty cells."""
    with path.open(newline="") as f:
        return [{k: parse_cell(v) for k, v in r.items()} for r in csv.DictReader(f)]


def parse_cell(text: str) -> Any:
    if text == "":
        return None
    if text in ("True", "False"):
        return text == "True"
    try:
        return int(text)
    except ValueError:
        pass
    try:
        x = float(text)
    except ValueError:
        return text
    return x if math.isfinite(x) or text.lower() in ("nan", "inf", "-inf") else text
