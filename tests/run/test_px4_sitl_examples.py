"""PX4 SITL's own services through `harness run`, with MAVSDK (gRPC API) scripts of ours in the style of the
MAVSDK-Python examples: calibration, gimbal, MAVFTP, the MAVLink shell and reboot. Each script exits 0 *and*
the vehicle's side shows what the script was told (parameters saved, the gimbal's attitude in the tlog, the
downloaded ULog identical to the vehicle's, the shell's answers)."""

from __future__ import annotations

import json
import math
import re

import pytest
from pymavlink import mavutil

from harness.autopilot.params import PARAM_DEFS

from .flights import Fly, flown

pytestmark = pytest.mark.sim


def test_calibration_of_every_sensor(harness_run: Fly) -> None:
    run = flown(harness_run, "calibration.py")
    out = run.mission_output(0)
    for name in ("gyroscope", "accelerometer", "magnetometer", "level horizon"):
        assert f"-- {name} calibration finished" in out
    assert "accelerometer: back side done, rotate to a different side" in out
    assert "gyroscope: 100 %" in out and "-- CAL_GYRO0_ID 1310988" in out
    saved = json.loads((run.out / "params" / "vehicle-0.json").read_text())
    assert saved["CAL_ACC0_ID"] == 1310988 and saved["CAL_MAG0_ID"] == 197388 and "SENS_BOARD_X_OFF" in saved


def test_gimbal_found_controlled_and_recorded(harness_run: Fly) -> None:
    run = flown(harness_run, "gimbal.py")
    out = run.mission_output(0)
    assert "Found gimbal: id=1, model=sim 2-axis gimbal" in out and "-- Control: PRIMARY" in out
    pitches = [float(p) for p in re.findall(r"pitch: (-?[\d.]+)", out)]
    assert min(pitches) == pytest.approx(-90.0, abs=0.5) and 15.0 < max(pitches) < 21.0  # down; 5 deg/s for 4 s
    yaws = [float(y) for y in re.findall(r"yaw: (-?[\d.]+)", out)]
    assert max(yaws) == pytest.approx(90.0, abs=0.5)
    # the gimbal's attitude is in the vehicle's telemetry log
    log = mavutil.mavlink_connection(str(run.out / "vehicle-0.tlog"))
    seen = []
    while (m := log.recv_match(type="GIMBAL_DEVICE_ATTITUDE_STATUS")) is not None:
        w, x, y, z = m.q
        seen.append(math.degrees(math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))))
    assert len(seen) > 50 and min(seen) == pytest.approx(-90.0, abs=0.5)


def test_mavftp_walks_downloads_uploads(harness_run: Fly) -> None:
    run = flown(harness_run, "ftp.py")
    out = run.mission_output(0)
    assert "-- / : etc/, log/, parameters.json" in out
    day = re.search(r"-- /log : (\S+)/", out)
    assert day is not None
    got = re.search(r"-- Downloaded /log/\S+/(\S+\.ulg): (\d+) of (\d+) bytes", out)
    assert got is not None and got.group(2) == got.group(3) and int(got.group(2)) > 10_000
    downloaded = (run.out / "ftp-download" / got.group(1)).read_bytes()
    written = (run.out / "vehicle-0.ulg").read_bytes()  # kept growing after the download
    assert len(downloaded) == int(got.group(2)) and downloaded == written[: len(downloaded)]
    assert "-- Uploaded, identical: True" in out and "renamed.txt (1100 B)" in out
    assert "-- /etc after clean-up: extras/, init.d-posix/" in out


def test_shell_answers_commands(harness_run: Fly) -> None:
    run = flown(harness_run, "shell.py")
    out = run.mission_output(0)
    assert "NuttShell (NSH)" in out and out.count("nsh> ") >= 4
    assert "FW version: 1.15.0" in out
    assert "x   MIS_TAKEOFF_ALT [" in out and f"{len(PARAM_DEFS)} parameters total." in out
    assert "MIS_TAKEOFF_ALT: curr: 2.5000 -> new: 4.0000" in out
    assert "TOPIC: vehicle_status" in out and "nav_state_name: HOLD" in out
    assert json.loads((run.out / "params" / "vehicle-0.json").read_text())["MIS_TAKEOFF_ALT"] == 4.0


def test_reboot_on_the_ground(harness_run: Fly) -> None:
    run = flown(harness_run, "reboot.py")
    out = run.mission_output(0)
    assert "-- Vehicle says: ['Rebooted: flight stack restarted']" in out
    assert "MPC_XY_CRUISE = 6.5" in out and "-- Armed after the reboot" in out
