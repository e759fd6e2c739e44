"""`harness run` end to end: real processes, real MAVSDK scripts, recordings, Ctrl-C."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from harness.record.world import read_topics

pytestmark = pytest.mark.sim
ROOT = Path(__file__).resolve().parents[2]
TAKEOFF_AND_LAND = ROOT / "missions" / "takeoff_and_land.py"


def harness(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "harness.cli", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def pids_with_run_dir(run_dir: Path) -> list[int]:
    """Every live process started for this run (they all carry HARNESS_RUN_DIR in their environment)."""
    found = []
    needle = f"HARNESS_RUN_DIR={run_dir}".encode()
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            env = Path(f"/proc/{entry}/environ").read_bytes()
        except OSError:
            continue
        if needle in env.split(b"\0"):
            found.append(int(entry))
    return found


def tlog_messages(path: Path) -> list[str]:
    log = mavutil.mavlink_connection(str(path))
    types = []
    while (m := log.recv_match()) is not None:
        types.append(m.get_type())
    return types


def test_three_vehicles_fly_the_same_unmodified_script(tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc = harness("run", "--vehicles", "3", "--mission", str(TAKEOFF_AND_LAND), "--out", str(out), "--duration", "200")
    stdout, stderr = proc.communicate(timeout=240)
    assert proc.returncode == 0, stdout + stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "ok" and summary["sim_time_s"] > 30
    for v in summary["vehicles"]:
        assert v["mission_exit_code"] == 0
        assert 9.7 <= v["max_altitude_m"] <= 10.5  # set_takeoff_altitude(10) from the script
        assert v["landed"] is True and v["crashed"] is False
    # each script reached its own vehicle: they started on a 5 m grid and each landed where it started
    finals = [v["final_position_ned_m"] for v in summary["vehicles"]]
    assert abs(finals[1][1] - finals[0][1] - 5.0) < 1.5 and abs(finals[2][0] - finals[0][0] + 5.0) < 1.5
    # the recordings open: tlog in pymavlink (what MAVExplorer uses), mcap with a pose stream >= 50 Hz
    for i in range(3):
        types = tlog_messages(out / f"vehicle-{i}.tlog")
        assert "HEARTBEAT" in types and "GLOBAL_POSITION_INT" in types and "COMMAND_LONG" in types
    topics = read_topics(out / "world.mcap")
    poses = topics["/vehicle/0/pose"]
    assert len(poses) >= 50 * summary["sim_time_s"] * 0.95
    assert not pids_with_run_dir(out)


def test_ctrl_c_stops_everything_and_keeps_the_recording(tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc = harness("run", "--vehicles", "2", "--mission", str(TAKEOFF_AND_LAND), "--out", str(out), "--speed", "2")
    # wait (wall clock, generous for a loaded machine) until the run has simulated a second: the summary it
    # rewrites every second while it runs says how far it got
    deadline = time.monotonic() + 120
    simulated = 0.0
    while time.monotonic() < deadline and simulated < 1.0:
        time.sleep(0.2)
        with contextlib.suppress(OSError, ValueError):
            simulated = float(json.loads((out / "summary.json").read_text()).get("sim_time_s", 0.0))
    assert simulated >= 1.0, "the run did not start simulating within 120 s"
    children = pids_with_run_dir(out)
    assert len(children) >= 2  # the two missions (and their mavsdk_server; the autopilots run in-process)
    # the run's own processes reach the root channel through a unix socket (no --accept, no remote vehicles)
    env = dict(v.split(b"=", 1) for v in Path(f"/proc/{children[0]}/environ").read_bytes().split(b"\0") if b"=" in v)
    address = env[b"HARNESS_CHANNEL"].decode()
    # ... in Linux's abstract namespace: no file, so nothing is left behind even by kill -9
    assert address.startswith("unix://@") and address.removeprefix("unix://") in _listening_unix_sockets()
    start = time.monotonic()
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=10)
    assert time.monotonic() - start < 5.0
    assert not pids_with_run_dir(out), "no orphans"
    assert address.removeprefix("unix://") not in _listening_unix_sockets(), "the channel's socket is closed"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["sim_time_s"] > 0
    assert proc.returncode == 130
    assert "HEARTBEAT" in tlog_messages(out / "vehicle-0.tlog")
    assert read_topics(out / "world.mcap")["/vehicle/1/pose"]


def test_bad_mission_path_is_one_line(tmp_path: Path) -> None:
    proc = harness("run", "--vehicles", "1", "--mission", str(tmp_path / "nope.py"), "--out", str(tmp_path / "r"))
    _, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 2
    assert stderr.strip().count("\n") == 0 and "nope.py" in stderr and "does not exist" in stderr


def _listening_unix_sockets() -> set[str]:
    """The names of the unix sockets bound on this machine (abstract ones start with ``@``)."""
    lines = Path("/proc/net/unix").read_text().splitlines()[1:]
    return {fields[7] for fields in (line.split() for line in lines) if len(fields) >= 8}
