"""Helpers shared by the end-to-end tests: fly one of our missions, start `harness sitl` for a ground station."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from harness.pytest_plugin import RunRecord

MISSIONS = Path(__file__).resolve().parents[2] / "missions"
Fly = Callable[..., RunRecord]


def running_sim_time(out: Path) -> float:
    """The sim time a running ``harness run`` has reached by its checkpoint in ``out`` (0 before, or once over)."""
    try:
        summary = json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        return 0.0
    return float(summary["sim_time_s"]) if summary.get("status") == "running" else 0.0


def wait_for_sim_time(proc: subprocess.Popen[str], out: Path, sim_s: float, wall_timeout_s: float) -> None:
    """Until the running ``harness run`` ``proc`` has recorded ``sim_s`` of sim time in ``out`` (asserted)."""
    deadline = time.monotonic() + wall_timeout_s
    while time.monotonic() < deadline and running_sim_time(out) < sim_s:
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.2)
    assert running_sim_time(out) >= sim_s, f"the run never recorded {sim_s:g} s of sim time"


def flown(harness_run: Fly, script: str, *args: str) -> RunRecord:
    """Fly ``missions/<script>`` on one vehicle; it must exit 0 and the run must succeed."""
    run = harness_run(mission=MISSIONS / script, vehicles=1, duration_s=600, args=list(args))
    assert run.ok, run.message
    assert run.vehicle(0).mission_exit_code == 0
    return run


def start_sitl(
    vehicles: int, out: Path, stdout: int | None = None, extra: Sequence[str] = ()
) -> tuple[subprocess.Popen[str], int]:
    """`harness sitl` (``extra``: more options) and the GCS port it reports (read from its stderr, which stays
    a pipe)."""
    proc, gcs, _ = start_sitl_ports(vehicles, out, stdout, extra)
    return proc, gcs


def start_sitl_ports(
    vehicles: int, out: Path, stdout: int | None = None, extra: Sequence[str] = ()
) -> tuple[subprocess.Popen[str], int, int]:
    """`harness sitl`, its GCS port and the UDP port vehicle 0 listens on."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "harness.cli", "sitl", "--vehicles", str(vehicles), "--out", str(out), *extra],
        stdout=stdout if stdout is not None else subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stderr is not None
    for _ in range(50):  # the ports line comes first unless something warned before it
        line = proc.stderr.readline()
        found = re.search(r"ground station on udp port (\d+); vehicle i listens on udp port (\d+)", line)
        if found:
            return proc, int(found.group(1)), int(found.group(2))
        if not line:
            break
    proc.kill()
    proc.wait(10)
    raise AssertionError("harness sitl did not report its GCS port")
