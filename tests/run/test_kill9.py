"""`kill -9` of `harness run`: no process left, a recording every reader opens, a run directory that says so."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest
from mcap.reader import make_reader

from harness.pytest_plugin import RunRecord
from harness.record.status import read_summary
from tests.run.flights import wait_for_sim_time
from tests.run.test_run import ROOT, harness, pids_with_run_dir

pytestmark = pytest.mark.sim
HOVER = ROOT / "missions" / "hover.py"


def test_kill_9_leaves_a_readable_recording_and_says_the_run_did_not_finish(tmp_path: Path) -> None:
    out = tmp_path / "run"
    # a mission that flies for minutes: the run is killed in the middle, however slow the machine
    proc = harness("run", "--vehicles", "1", "--mission", str(HOVER), "--out", str(out), "--speed", "2", "--", "300")
    try:
        wait_for_sim_time(proc, out, 15.0, 120)
        assert pids_with_run_dir(out), "the mission process runs"
    finally:
        _kill_9_and_expect_no_child(proc, out)

    # the run directory says the run did not finish, with the sim time it reached
    summary = read_summary(out)
    assert summary["status"] == "killed" and summary["finished"] is False
    assert summary["sim_time_s"] >= 15.0 and "did not finish" in summary["message"]
    raw = json.loads((out / "summary.json").read_text())
    assert raw["status"] == "running"  # what was on disk: read_summary tells that the process is gone

    # mcap's own reader opens world.mcap and the vehicle's track reaches the last checkpoint
    with (out / "world.mcap").open("rb") as f:
        states = [
            json.loads(m.data)
            for _, ch, m in make_reader(f).iter_messages(topics=["/vehicle/0/state"])
            if ch.topic == "/vehicle/0/state"
        ]
    assert states, "no vehicle state in world.mcap"
    last_t = states[-1]["t_s"]
    assert last_t >= summary["sim_time_s"] - 0.5, (last_t, summary["sim_time_s"])
    assert max(-s["pos_ned_m"][2] for s in states) > 1.0, "the track holds the take-off"

    # the plugin's reader and harness plot work on it
    record = RunRecord(out, -9, "", "")
    assert record.summary["status"] == "killed" and not record.ok
    assert len(record.vehicle(0).track) == len(states)
    plot = subprocess.run(
        [sys.executable, "-m", "harness.cli", "plot", str(out)], capture_output=True, text=True, timeout=120
    )
    assert plot.returncode == 0, plot.stderr
    assert "the run did not finish" in plot.stderr
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert "trajectories.png" in pngs and len(pngs) >= 2, pngs
    assert "did not finish" in (out / "index.html").read_text()

    # world.rrd (when Rerun is installed) streams: its reader gets the track up to about the same time
    if (out / "world.rrd").is_file():
        from tests.record.test_rrd import read_rrd

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "RRD file has no footer": a killed run's file, read as a stream
            rrd = read_rrd(out / "world.rrd")
        times = rrd["/world/vehicle/0"]["sim_time"]
        assert times and max(times) >= summary["sim_time_s"] - 2.0, (max(times or [0]), summary["sim_time_s"])


def test_kill_9_right_after_the_children_started_leaves_no_process(tmp_path: Path) -> None:
    """The children tie themselves to the run after they start (no preexec_fn): killed before or while they
    do, not one of them (nor anything they started) survives."""
    out = tmp_path / "run"
    argv = ["run", "--vehicles", "3", "--workers", "2", "--network", "builtin", "--mission", str(HOVER)]
    proc = harness(*argv, "--out", str(out), "--speed", "2", "--", "300")
    try:
        # an autopilot host, the network and three missions: kill as soon as all five exist
        deadline = time.monotonic() + 120
        while len(started := pids_with_run_dir(out)) < 5 and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.005)
        assert len(started) >= 5, started
    finally:
        _kill_9_and_expect_no_child(proc, out)
    raw = json.loads((out / "summary.json").read_text())
    assert raw["status"] == "running" and raw["sim_time_s"] == 0.0, "killed before the first tick"


def _kill_9_and_expect_no_child(proc: subprocess.Popen[str], out: Path) -> None:
    """``kill -9`` the run; within 5 s not one process of its run directory may be left."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=10)
    gone = time.monotonic() + 5.0
    while pids_with_run_dir(out) and time.monotonic() < gone:
        time.sleep(0.1)
    assert not pids_with_run_dir(out), "every child of the killed run is gone"
