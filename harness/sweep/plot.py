"""``harness plot DIR`` on a sweep: each metric against each swept parameter, one PNG each, and index.html.

Metrics are the numeric columns of results.csv: ``sim_time_s``, ``wall_time_s``, ``real_time_factor``, and
every per-vehicle column (``v<i>.max_altitude_m``, ``v<i>.final_north_m``, mission metrics ...), drawn with
one series per vehicle. Every run is a point (runs that did not end ok are red crosses); the line joins the
mean over seeds at each value. Parameters are the ``--set`` paths, or ``seed`` when only seeds were swept.
"""

from __future__ import annotations

import html
import json
import re
from collections import defaultdict
from pathlib import Path
from typing import Any

from harness.core.errors import ScenarioError
from harness.run.result import RunStatus
from harness.sweep.results import read_results

_SKIP = {"seed", "faults", "mission_exit_code"}
_RUN_METRICS = ("sim_time_s", "wall_time_s", "real_time_factor")


def sweep_metrics(rows: list[dict[str, Any]]) -> dict[str, list[str]]:
    """Metric name → its columns (``max_altitude_m`` → ``[v0.max_altitude_m, v1.max_altitude_m]``)."""
    out: dict[str, list[str]] = {m: [m] for m in _RUN_METRICS if any(_number(r.get(m)) for r in rows)}
    per: dict[str, list[str]] = defaultdict(list)
    for col in sorted({k for r in rows for k in r}):
        m = re.match(r"^v(\d+)\.(.+)$", col)
        if m is None or m.group(2) in _SKIP:
            continue
        if any(_number(r.get(col)) for r in rows):
            per[m.group(2)].append(col)
    for name, cols in per.items():
        out[name] = sorted(cols, key=lambda c: int(c[1:].split(".", 1)[0]))
    return out


def _number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def make_sweep_plots(sweep_dir: Path) -> list[Path]:
    """Write ``<metric>_vs_<param>.png`` for every pair and ``index.html``; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    csv_path = sweep_dir / "results.csv"
    if not csv_path.is_file():
        raise ScenarioError(f"harness plot: {csv_path} does not exist (has the sweep finished a run yet?)")
    spec = json.loads((sweep_dir / "sweep.json").read_text())
    rows = read_results(csv_path)
    params = [p["path"] for p in spec.get("parameters", [])] or ["seed"]
    written: list[Path] = []
    for metric, cols in sweep_metrics(rows).items():
        for param in params:
            xs_all = [r.get(param) for r in rows]
            categorical = not all(_number(x) for x in xs_all if x is not None)
            ticks = sorted({str(x) for x in xs_all}) if categorical else []
            fig, ax = plt.subplots(figsize=(7, 4))
            for col in cols:
                means: dict[float, list[float]] = defaultdict(list)
                color = None
                for r in rows:
                    x: Any = r.get(param)
                    value: Any = r.get(col)
                    if x is None or not _number(value):
                        continue
                    y = float(value)
                    xv = float(ticks.index(str(x))) if categorical else float(x)
                    ok = r.get("status") == RunStatus.OK
                    pts = ax.plot([xv], [y], "o" if ok else "x", color=color if ok else "red", alpha=0.6)
                    if ok and color is None:
                        color = pts[0].get_color()
                    means[xv].append(y)
                if means:
                    mx = sorted(means)
                    ax.plot(mx, [sum(means[x]) / len(means[x]) for x in mx], "-", color=color, label=col)
            if categorical:
                ax.set_xticks(range(len(ticks)), ticks)
            ax.set_xlabel(param)
            ax.set_ylabel(metric)
            ax.set_title(f"{metric} vs {param} ({len(rows)} runs; line: mean over seeds)")
            ax.grid(True)
            if len(cols) > 1:
                ax.legend(fontsize="small")
            fig.tight_layout()
            path = sweep_dir / f"{_file(metric)}_vs_{_file(param)}.png"
            fig.savefig(path, dpi=90)
            plt.close(fig)
            written.append(path)
    written.append(_html(sweep_dir, spec, rows, written))
    return written


def _file(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_-]+", "_", name)


def _html(sweep_dir: Path, spec: dict[str, Any], rows: list[dict[str, Any]], images: list[Path]) -> Path:
    cols = list(rows[0]) if rows else []
    head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(_fmt(r.get(c)))}</td>" for c in cols) + "</tr>" for r in rows)
    ok = sum(1 for r in rows if r.get("status") == RunStatus.OK)
    imgs = "".join(f'<h3>{html.escape(p.stem)}</h3><img src="{p.name}" style="max-width:100%">' for p in images)
    page = (
        "<!doctype html><html><head><meta charset='utf-8'><title>uav-harness sweep</title></head><body>"
        f"<h1>Sweep {html.escape(sweep_dir.name)}</h1><p>scenario {html.escape(str(spec.get('scenario')))}, "
        f"{len(rows)} runs, {ok} ok</p>{imgs}<h2>results.csv</h2>"
        f"<table border=1 cellpadding=3 style='font-size:small'><tr>{head}</tr>{body}</table></body></html>"
    )
    out = sweep_dir / "index.html"
    out.write_text(page)
    return out


def _fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.3g}"
    return str(v)
