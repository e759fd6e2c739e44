"""PX4 features through `harness run`, checked in the recording (world.mcap track, vehicle-0.tlog, the ULog):
failure injection, follow me, log download and manual control — our own scripts in missions/ (always), and
MAVSDK-Python's own examples unmodified when its repository mirror is on this machine (skipped otherwise,
e.g. in CI)."""

from __future__ import annotations

import math
import os
import subprocess
from pathlib import Path

import pytest
from pymavlink import mavutil

from harness.autopilot.api import FlightMode
from harness.pytest_plugin import RunRecord, VehicleRecord

from .flights import Fly, flown

pyulog = pytest.importorskip("pyulog")
pytestmark = pytest.mark.sim

MIRROR = Path(os.environ.get("MAVSDK_PYTHON_MIRROR", "/work/.mirror/mavlink+MAVSDK-Python/repo"))


def fetched_example(name: str, into: Path) -> Path:
    """MAVSDK-Python's ``examples/<name>`` copied out of the mirror (the test skips without it)."""
    if not MIRROR.is_dir():
        pytest.skip(f"no MAVSDK-Python mirror at {MIRROR} (set MAVSDK_PYTHON_MIRROR): its examples are not run")
    text = subprocess.run(
        ["git", f"--git-dir={MIRROR}", "show", f"HEAD:examples/{name}"], capture_output=True, text=True, check=True
    ).stdout
    path = into / name
    path.write_text(text)
    return path


def tlog(run: RunRecord) -> tuple[list[tuple[float, FlightMode | None]], list[tuple[float, str]], list[object]]:
    """From vehicle-0.tlog: (time, mode) at every mode change, (time, text) of every STATUSTEXT, every message."""
    log = mavutil.mavlink_connection(str(run.out / "vehicle-0.tlog"))
    modes: list[tuple[float, FlightMode | None]] = []
    texts: list[tuple[float, str]] = []
    msgs = []
    while (m := log.recv_match()) is not None:
        msgs.append(m)
        if m.get_srcSystem() != 1:
            continue
        t = getattr(m, "_timestamp", 0.0)
        if m.get_type() == "HEARTBEAT":
            mode = FlightMode.from_custom_mode(m.custom_mode)
            if not modes or modes[-1][1] != mode:
                modes.append((t, mode))
        elif m.get_type() == "STATUSTEXT":
            texts.append((t, m.text))
    return modes, texts, msgs


def ulog_nav_states(run: RunRecord) -> list[int]:
    status = pyulog.ULog(str(run.out / "vehicle-0.ulg")).get_dataset("vehicle_status")
    return [int(s) for s in status.data["nav_state"]]


def airborne_track(v: VehicleRecord, above_m: float = 1.0) -> list[dict[str, object]]:
    return [m for m in v.track if -m["pos_ned_m"][2] > above_m]


# ------------------------------------------------------------------------------------------- failure injection
def check_gps_failure(run: RunRecord) -> None:
    """GPS off at ~22 m: GPS health goes, the position is declared lost, the vehicle descends (AUTO.LAND)."""
    modes, texts, msgs = tlog(run)
    injected = [t for t, text in texts if "sensor_gps off" in text]
    lost = [t for t, text in texts if "position estimate invalid" in text]
    assert injected and lost and injected[0] <= lost[0], texts
    assert [m for t, m in modes if t >= injected[0]][-1:] == [FlightMode.LAND]  # (tlog stamps are wall time)
    gps_health = [bool(m.onboard_control_sensors_health & 0x20) for m in msgs if m.get_type() == "SYS_STATUS"]  # type: ignore[attr-defined]
    assert True in gps_health and gps_health[-1] is False  # healthy before, not after
    assert 18 in ulog_nav_states(run)  # AUTO_LAND in the flight log too
    v = run.vehicle(0)
    assert v.max_altitude_m > 18.0 and not v.crashed


def test_failure_injection_mission_gps_off_descends_and_lands(harness_run: Fly) -> None:
    run = flown(harness_run, "failure_injection.py")
    out = run.mission_output(0)
    assert out.index("-- Injecting GPS failure") < out.index("Flight mode: LAND") < out.index("-- Landed without GPS")
    check_gps_failure(run)
    v = run.vehicle(0)
    assert v.landed and -v.final_position_ned_m[2] < 0.5


def test_mavsdk_failure_injection_example(harness_run: Fly, tmp_path: Path) -> None:
    script = fetched_example("failure_injection.py", tmp_path)
    run = harness_run(mission=script, vehicles=1, duration_s=300)
    assert run.ok, run.message
    assert "-- Injecting GPS failure" in run.mission_output(0)
    check_gps_failure(run)
    v = run.vehicle(0)
    # the script exits 20 s after the failure: by then the vehicle has come well down from its 22 m
    assert -v.final_position_ned_m[2] < v.max_altitude_m - 5.0


# ------------------------------------------------------------------------------------------- follow me
def test_follow_me_mission_follows_the_walking_target(harness_run: Fly) -> None:
    run = flown(harness_run, "follow_me.py")
    v = run.vehicle(0)
    modes, _, _ = tlog(run)
    assert FlightMode.FOLLOW_TARGET in [m for _, m in modes]
    # the target walks to 48 m north, then 20 m east; the vehicle keeps 6 m behind it at 8 m above home
    north_leg = [m for m in v.track if 20.0 < m["pos_ned_m"][0] < 35.0]
    assert north_leg and all(-m["pos_ned_m"][2] == pytest.approx(8.0, abs=1.0) for m in north_leg)
    assert all(abs(m["pos_ned_m"][1]) < 1.5 for m in north_leg)
    n, e, _ = v.final_position_ned_m
    assert n == pytest.approx(48.0, abs=2.0) and e == pytest.approx(14.0, abs=2.0)  # 6 m behind (west of) it
    assert v.landed
    assert 19 in ulog_nav_states(run)  # AUTO_FOLLOW_TARGET


def test_mavsdk_follow_me_example(harness_run: Fly, tmp_path: Path) -> None:
    script = fetched_example("follow_me_example.py", tmp_path)
    run = harness_run(mission=script, vehicles=1, duration_s=300)
    assert run.ok, run.message
    modes, _, _ = tlog(run)
    assert FlightMode.FOLLOW_TARGET in [m for _, m in modes]
    v = run.vehicle(0)
    # its fake targets lie 33 m north, then 44 m west of home: the vehicle heads there (2 s per target)
    assert max(m["pos_ned_m"][0] for m in v.track) > 10.0
    assert min(m["pos_ned_m"][1] for m in v.track) < -10.0
    assert not v.crashed


# ------------------------------------------------------------------------------------------- log download
def check_downloaded(path: Path, run: RunRecord) -> None:
    """The whole log the vehicle announced (LOG_ENTRY size), identical to its file, a ULog pyulog reads."""
    _, _, msgs = tlog(run)
    sizes = [m.size for m in msgs if m.get_type() == "LOG_ENTRY"]  # type: ignore[attr-defined]
    assert sizes and path.stat().st_size == sizes[-1]
    assert path.read_bytes() == (run.out / "vehicle-0.ulg").read_bytes()[: path.stat().st_size]
    log = pyulog.ULog(str(path))
    names = {d.name for d in log.data_list}
    assert {
        "vehicle_local_position",
        "vehicle_attitude",
        "sensor_combined",
        "battery_status",
        "vehicle_status",
    } <= names


def test_logfile_download_mission_gets_the_flight(harness_run: Fly) -> None:
    run = flown(harness_run, "logfile_download.py")
    assert "-- Downloaded" in run.mission_output(0)
    path = run.out / "log-0.ulg"
    check_downloaded(path, run)
    z = pyulog.ULog(str(path)).get_dataset("vehicle_local_position").data["z"]
    assert min(z) == pytest.approx(-5.0, abs=0.7)  # the 5 m flight is in the downloaded log


def test_mavsdk_logfile_download_example(harness_run: Fly, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    script = fetched_example("logfile_download.py", tmp_path)
    work = tmp_path / "cwd"
    work.mkdir()
    monkeypatch.chdir(work)  # the example writes ./log-<date>.ulog
    root = str(Path(__file__).resolve().parents[2])  # this tree's harness, also when PYTHONPATH is relative
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")])))
    run = harness_run(mission=script, vehicles=1, duration_s=120)
    assert run.ok, run.message
    assert "Downloading: log 0" in run.mission_output(0)
    (path,) = work.glob("log-*.ulog")
    check_downloaded(path, run)


# ------------------------------------------------------------------------------------------- manual control
def test_manual_control_mission_moves_with_the_sticks(harness_run: Fly) -> None:
    run = flown(harness_run, "manual_control.py")
    v = run.vehicle(0)
    modes, _, msgs = tlog(run)
    seen = [m for _, m in modes]
    assert FlightMode.POSCTL in seen and FlightMode.ALTCTL in seen
    assert sum(1 for m in msgs if m.get_type() == "MANUAL_CONTROL") > 200  # type: ignore[attr-defined]
    track = airborne_track(v)
    north = max(m["pos_ned_m"][0] for m in track)
    east = max(m["pos_ned_m"][1] for m in track)
    assert north > 15.0 and east > 15.0  # 3 s of full forward, then 3 s of full right (MPC_VEL_MANUAL 10 m/s)
    assert v.max_altitude_m > 9.0  # 2 s of full throttle from 5 m (MPC_Z_VEL_MAX_UP 3 m/s)
    # sticks centred after the forward leg: it braked and held (no drift of more than 1 m over 2 s)
    braked = [m for m in track if abs(m["vel_ned_m_s"][0]) < 0.2 and m["pos_ned_m"][0] > 20.0 and m["pos_ned_m"][1] < 1]
    assert len(braked) > 20  # 50 Hz samples
    assert v.landed


def test_mavsdk_manual_control_example(harness_run: Fly, tmp_path: Path) -> None:
    """The example sends random sticks for ever: the run ends at its duration with the script still running."""
    script = fetched_example("manual_control.py", tmp_path)
    run = harness_run(mission=script, vehicles=1, duration_s=60)
    assert "still running" in str(run.summary.get("message")), run.message
    assert "-- Starting manual control" in run.mission_output(0)
    modes, _, _ = tlog(run)
    assert FlightMode.POSCTL in [m for _, m in modes]
    v = run.vehicle(0)
    track = airborne_track(v, 0.5)
    speeds = [math.hypot(*m["vel_ned_m_s"][:2]) for m in track]
    yaws = [yaw for t, _, _, yaw in v.attitudes_deg() if t >= track[0]["t_s"]]
    print(f"manual_control.py: top speed {max(speeds):.2f} m/s, yaw span {max(yaws) - min(yaws):.0f} deg")
    # random full-stick pulses of 0.1 s: speeds a hover never reaches, and yaw swung by the yaw stick
    assert max(speeds) > 0.8 and max(yaws) - min(yaws) > 30.0
    assert not v.crashed
