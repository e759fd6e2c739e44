"""ArduPilot SITL's ``SIM_*`` parameters acting on the simulated world, set over MAVLink during a flight (issue 34),
and the world PX4 SITL's environment variables ask for.

The pymavlink script (``sim_params_mission.py``) hovers in GUIDED at 10 m over SERIAL0, sets ``SIM_WIND_DIR 270``
and ``SIM_WIND_SPD 10`` (each echoed by PARAM_VALUE), hovers 25 s, then ``SIM_GPS_DISABLE 1``. Measured from the
ground truth in ``world.mcap``."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from harness.pytest_plugin import RunRecord
from harness.scenario.sitl_defaults import CMAC

pytestmark = pytest.mark.sim

HERE = Path(__file__).resolve().parent


def thrust_direction(q: dict[str, float]) -> tuple[float, float]:
    """(tilt from vertical, azimuth of the lean) in degrees, from a pose's orientation (body to NED)."""
    w, x, y, z = q["w"], q["x"], q["y"], q["z"]
    up = (-2 * (x * z + w * y), -2 * (y * z - w * x), -(1 - 2 * (x * x + y * y)))  # the thrust axis (-body z)
    return math.degrees(math.acos(-up[2])), math.degrees(math.atan2(up[1], up[0]))


def test_sim_wind_leans_the_copter_and_sim_gps_disable_lands_it(harness_run) -> None:  # type: ignore[no-untyped-def]
    run: RunRecord = harness_run(
        mission=HERE / "sim_params_mission.py", duration_s=200, extra=["--firmware", "ardupilot"]
    )
    assert run.ok, run.message
    out = run.mission_output(0)
    for line in ("PARAM_VALUE SIM_WIND_DIR 270", "PARAM_VALUE SIM_WIND_SPD 10", "PARAM_VALUE SIM_GPS_DISABLE 1"):
        assert line in out, out
    fix = run.topics["/vehicle/0/fix"][0]
    # the ground truth at the start: CMAC within 1 cm (1e-7 deg is 1.1 cm of latitude)
    assert abs(fix["latitude"] - CMAC[0]) < 9e-8 and abs(fix["longitude"] - CMAC[1]) < 1e-7
    changes = [e for e in run.topics["/sim/events"] if e["kind"] == "sim"]
    assert len(changes) == 2, changes  # DIR, then SPD: each applied at a tick boundary and recorded
    t_wind = changes[1]["t_s"]
    n, e, d = changes[1]["detail"]["wind_ned_m_s"]
    assert abs(n) < 1e-9 and math.isclose(e, 10.0) and d == 0.0  # from the west: the air moves east
    v = run.vehicle(0)
    before = [
        thrust_direction(p["pose"]["orientation"])
        for s, p in zip(v.track, v.poses, strict=True)
        if t_wind - 5 < s["t_s"] < t_wind
    ]
    windy = [
        thrust_direction(p["pose"]["orientation"])
        for s, p in zip(v.track, v.poses, strict=True)
        if t_wind + 10 < s["t_s"] < t_wind + 24
    ]
    tilt_before = sum(t for t, _ in before) / len(before)
    tilt = sum(t for t, _ in windy) / len(windy)
    azimuth = sum(a for _, a in windy) / len(windy)
    print(
        f"FIGURE SIM_WIND_SPD 10 / DIR 270: lean {tilt:.2f} deg toward azimuth {azimuth:.1f} (before {tilt_before:.2f})"
    )
    assert tilt_before < 1.5 and tilt >= 2.0 and -100.0 < azimuth < -80.0  # into the wind: west
    # SIM_GPS_DISABLE 1: no GPS (fix type 0), the position estimate lost, ArduCopter's EKF failsafe lands
    assert "GPS fix_type 0" in out and "TEXT EKF variance" in out and "MODE LAND" in out and "DISARMED True" in out, out
    assert v.landed and not v.crashed


def test_px4_home_and_speed_factor_move_and_pace_a_px4_vehicle(tmp_path: Path) -> None:
    env = dict(os.environ, PX4_HOME_LAT="28.452386", PX4_HOME_LON="-13.867138", PX4_HOME_ALT="28.5")
    env["PX4_SIM_SPEED_FACTOR"] = "5"
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "harness.cli", "run", "--vehicles", "1", "--duration", "20", "--out", str(out)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    run = RunRecord(out, proc.returncode, proc.stdout, proc.stderr)
    assert run.ok, run.message
    fix = run.topics["/vehicle/0/fix"][0]
    assert abs(fix["latitude"] - 28.452386) < 1e-7 and abs(fix["longitude"] + 13.867138) < 1e-7  # within 1 cm
    assert abs(fix["altitude"] - 28.5) < 0.2  # standing on the ground there (the FDM's skid height above it)
    pacing = run.summary["pacing"]
    rtf = pacing["sim_s"] / (pacing["wall_s"] - pacing["behind_s"])
    print(f"FIGURE PX4_SIM_SPEED_FACTOR=5: speed {pacing['speed']}, x{rtf:.2f} (wall {pacing['wall_s']:.2f} s)")
    assert pacing["speed"] == 5.0 and 4.75 < rtf < 5.25


SPEEDUP_SCRIPT = """
import time
from pymavlink import mavutil
m = mavutil.mavlink_connection("tcp:127.0.0.1:5760", source_system=255)
m.wait_heartbeat(timeout=30)
def param(name, value=None):
    if value is None:
        m.mav.param_request_read_send(m.target_system, m.target_component, name.encode(), -1)
    else:
        m.mav.param_set_send(m.target_system, m.target_component, name.encode(), value, 9)
    while True:
        msg = m.recv_match(type="PARAM_VALUE", blocking=True, timeout=10)
        if msg is not None and msg.param_id == name:
            return msg.param_value
print("SIM_SPEEDUP", param("SIM_SPEEDUP"), flush=True)
print("SIM_SPEEDUP", param("SIM_SPEEDUP", 10), flush=True)
time.sleep(30)
"""


def test_sim_speedup_is_the_runs_pace(tmp_path: Path) -> None:
    script = tmp_path / "speedup.py"
    script.write_text(SPEEDUP_SCRIPT)
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "harness.cli", "run", "--firmware", "ardupilot", "--speed", "1", "--mission",
         str(script), "--duration", "40", "--out", str(out), "--no-progress"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    run = RunRecord(out, proc.returncode, proc.stdout, proc.stderr)
    assert run.ok, run.message
    assert run.mission_output(0).split() == ["SIM_SPEEDUP", "1.0", "SIM_SPEEDUP", "10.0"]  # --speed 1, then 10
    ev = [e for e in run.topics["/sim/events"] if e["kind"] == "sim"]
    assert len(ev) == 1 and ev[0]["detail"]["speedup"] == 10.0
    pacing = run.summary["pacing"]
    print(f"FIGURE SIM_SPEEDUP 10 at {ev[0]['t_s']:.1f} s of a --speed 1 run: {pacing}")
    assert pacing["speed"] == 10.0 and pacing["wall_s"] < 0.5 * pacing["sim_s"]  # at x1 it would be >= 40 s


def test_sim_wind_from_a_scenario_acts_from_the_start(tmp_path: Path) -> None:
    """A PX4 vehicle with ``params = { SIM_WIND_SPD = 8, SIM_WIND_DIR = 0 }``: the wind blows from the first tick
    (recorded at t = 0) and the hover leans north, into it."""
    hover = Path(__file__).resolve().parents[2] / "missions" / "hover.py"
    (tmp_path / "s.toml").write_text(
        f'[[vehicles]]\nmission = "{hover}"\nargs = ["15"]\nparams = {{ SIM_WIND_SPD = 8, SIM_WIND_DIR = 0 }}\n'
    )
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "harness.cli", "run", str(tmp_path / "s.toml"), "--out", str(out), "--no-progress"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    run = RunRecord(out, proc.returncode, proc.stdout, proc.stderr)
    assert run.ok, run.message
    ev = [e for e in run.topics["/sim/events"] if e["kind"] == "sim"]
    assert len(ev) == 1 and ev[0]["t_s"] == 0.0 and ev[0]["detail"]["wind_ned_m_s"][0] == pytest.approx(-8.0)
    v = run.vehicle(0)
    aloft = [thrust_direction(p["pose"]["orientation"]) for s, p in zip(v.track, v.poses, strict=True)
             if -s["pos_ned_m"][2] > 5.0]  # fmt: skip
    tail = aloft[len(aloft) // 3 : 2 * len(aloft) // 3]
    tilt, az = sum(t for t, _ in tail) / len(tail), sum(a for _, a in tail) / len(tail)
    print(f"FIGURE scenario SIM_WIND_SPD 8 from north: lean {tilt:.2f} deg toward azimuth {az:.1f}")
    assert tilt >= 2.0 and abs(az) < 10.0
