"""``benchmarks/bench_view.py`` runs against today's recorders and reports a cost for each recording.

It drives ``WorldRecorder`` and ``RrdRecorder`` directly; when their interface changes (``VehicleSample``)
this catches a benchmark that no longer runs, which nothing else in the suite imports."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

pytest.importorskip("rerun", reason="the view extra is not installed (pip install 'uav-harness[view]')")


@pytest.mark.parametrize("serve", [False, True])
def test_bench_view_reports_the_cost_of_each_recording(serve: bool) -> None:
    proc = subprocess.run(
        [
            sys.executable,
            str(ROOT / "benchmarks" / "bench_view.py"),
            "2",
            "--sim",
            "3",
            *(["--serve"] if serve else []),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    header, row = proc.stdout.strip().splitlines()
    assert header.split()[0] == "vehicles"
    vehicles, mcap_cpu, rrd_cpu, rrd_mb, links_cpu = (float(x) for x in row.split())
    assert vehicles == 2 and mcap_cpu > 0 and rrd_cpu > 0 and rrd_mb > 0 and links_cpu >= 0
