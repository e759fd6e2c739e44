"""``harness plot DIR``: PNG plots and one HTML page from a run's recording.

Reads ``world.mcap`` (and ``summary.json`` when present) and writes into DIR:

- ``trajectories.png`` — top-down tracks of every vehicle (east right, north up), start and end marked;
- ``altitude.png`` — altitude above the origin over sim time;
- ``link_quality.png`` — delivered packets per second between vehicle pairs (from ``network-events.jsonl``),
  when the run had a network;
- ``real_time_factor.png`` — sim time per wall time over the run;
- ``index.html`` — all of them on one page with the summary.
"""

from __future__ import annotations

import html
import json
from collections import defaultdict
from pathlib import Path
from typing import Any

from harness.core.errors import ScenarioError
from harness.record.status import read_summary
from harness.record.world import read_topics


def _tracks(topics: dict[str, list[Any]]) -> dict[int, list[dict[str, Any]]]:
    tracks: dict[int, list[dict[str, Any]]] = {}
    for topic, msgs in topics.items():
        if topic.startswith("/vehicle/") and topic.endswith("/state"):
            tracks[int(topic.split("/")[2])] = msgs
    return dict(sorted(tracks.items()))


def make_plots(run_dir: Path) -> list[Path]:
    """Write the plots of ``run_dir``; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mcap = run_dir / "world.mcap"
    if not mcap.is_file():
        raise ScenarioError(f"harness plot: {mcap} does not exist (is {run_dir} the --out of a run?)")
    topics = read_topics(mcap)
    tracks = _tracks(topics)
    written: list[Path] = []

    fig, ax = plt.subplots(figsize=(7, 7))
    for v, msgs in tracks.items():
        n = [m["pos_ned_m"][0] for m in msgs]
        e = [m["pos_ned_m"][1] for m in msgs]
        (line,) = ax.plot(e, n, label=f"vehicle {v}")
        if n:
            ax.plot(e[0], n[0], "o", color=line.get_color())
            ax.plot(e[-1], n[-1], "x", color=line.get_color())
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_title("trajectories (o start, x end)")
    ax.axis("equal")
    ax.grid(True)
    if tracks:
        ax.legend()
    written.append(_save(fig, run_dir / "trajectories.png"))

    fig, ax = plt.subplots(figsize=(9, 4))
    for v, msgs in tracks.items():
        ax.plot([m["t_s"] for m in msgs], [-m["pos_ned_m"][2] for m in msgs], label=f"vehicle {v}")
    ax.set_xlabel("sim time (s)")
    ax.set_ylabel("altitude above origin (m)")
    ax.grid(True)
    if tracks:
        ax.legend()
    written.append(_save(fig, run_dir / "altitude.png"))

    deliveries: dict[tuple[int, int], dict[int, int]] = defaultdict(lambda: defaultdict(int))
    net_log = run_dir / "network-events.jsonl"
    if net_log.is_file():
        for text in net_log.read_text().splitlines():
            ev = json.loads(text)
            if ev.get("kind") == "deliver":
                deliveries[(ev["src"], ev["dst"])][int(ev["t_s"])] += 1
    if deliveries:
        fig, ax = plt.subplots(figsize=(9, 4))
        for (src, dst), per_s in sorted(deliveries.items()):
            xs = sorted(per_s)
            ax.plot(xs, [per_s[x] for x in xs], label=f"{src}→{dst}")
        ax.set_xlabel("sim time (s)")
        ax.set_ylabel("packets delivered per second")
        ax.grid(True)
        ax.legend(fontsize="small", ncol=2)
        written.append(_save(fig, run_dir / "link_quality.png"))

    ticks = topics.get("/sim/tick", [])
    if ticks:
        fig, ax = plt.subplots(figsize=(9, 3.5))
        xs, ys = [], []
        prev = ticks[0]
        for t in ticks[1:]:
            dw = t["wall_s"] - prev["wall_s"]
            if dw > 0:
                xs.append(t["t_s"])
                ys.append((t["t_s"] - prev["t_s"]) / dw)
            prev = t
        ax.plot(xs, ys)
        ax.set_xlabel("sim time (s)")
        ax.set_ylabel("real-time factor")
        ax.grid(True)
        written.append(_save(fig, run_dir / "real_time_factor.png"))

    written.append(_html(run_dir, written))
    return written


def _save(fig: Any, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


def _html(run_dir: Path, images: list[Path]) -> Path:
    summary_path = run_dir / "summary.json"
    summary = read_summary(run_dir) if summary_path.is_file() else {}  # a killed run: status "killed"
    rows = "".join(
        f"<tr><td>{v['id']}</td><td>{html.escape(str(v.get('mission')))}</td><td>{v.get('mission_exit_code')}</td>"
        f"<td>{v.get('max_altitude_m', 0):.1f}</td><td>{[round(x, 1) for x in v.get('final_position_ned_m', [])]}</td>"
        f"<td>{v.get('landed')}</td><td>{v.get('armed')}</td></tr>"
        for v in summary.get("vehicles", [])
    )
    head = (
        f"<p>status <b>{html.escape(str(summary.get('status', '?')))}</b>, sim {summary.get('sim_time_s', 0):.1f} s, "
        f"wall {summary.get('wall_time_s', 0):.1f} s, real-time factor {summary.get('real_time_factor', 0):.1f}</p>"
        f"<p>{html.escape(str(summary.get('message') or ''))}</p>"
        if summary
        else ""
    )
    imgs = "".join(f'<h2>{p.stem.replace("_", " ")}</h2><img src="{p.name}" style="max-width:100%">' for p in images)
    page = (
        "<!doctype html><html><head><meta charset='utf-8'><title>uav-harness run</title></head><body>"
        f"<h1>Run {html.escape(run_dir.name)}</h1>{head}"
        "<table border=1 cellpadding=4><tr><th>vehicle</th><th>mission</th><th>exit</th><th>max alt (m)</th>"
        f"<th>final NED (m)</th><th>landed</th><th>armed</th></tr>{rows}</table>{imgs}</body></html>"
    )
    out = run_dir / "index.html"
    out.write_text(page)
    return out
