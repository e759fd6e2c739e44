"""The MAVSDK-Python example repertoire, as our own scripts in missions/, through `harness run`.

One test per kind of example the MAVSDK-Python repository ships (telemetry during takeoff and land, mission
with progress and RTL, raw mission, offboard velocity NED and body, offboard attitude, orbit, geofence,
parameters, firmware version): each script exits 0 *and* the recording shows the vehicle did what the
script asked.
"""

from __future__ import annotations

import itertools
import math
import re
import statistics

import pytest

from harness.autopilot.mavlink.version import FLIGHT_SW_VERSION
from harness.autopilot.params import PARAM_DEFS, ParamType
from harness.pytest_plugin import VehicleRecord

from .flights import Fly, flown

pytestmark = pytest.mark.sim


def first_time_near(v: VehicleRecord, n: float, e: float, within_m: float) -> float | None:
    for m in v.track:
        if math.hypot(m["pos_ned_m"][0] - n, m["pos_ned_m"][1] - e) < within_m:
            return float(m["t_s"])
    return None


def landed_near(v: VehicleRecord, n: float, e: float, within_m: float) -> bool:
    fn, fe, _ = v.final_position_ned_m
    return v.landed and math.hypot(fn - n, fe - e) < within_m


def test_telemetry_during_takeoff_and_land(harness_run: Fly) -> None:
    run = flown(harness_run, "telemetry_takeoff_and_land.py")
    out = run.mission_output(0)
    altitudes = [float(a) for a in re.findall(r"Altitude: (-?[\d.]+) m", out)]
    v = run.vehicle(0)
    # the printed (estimated) altitude climbs to the 5 m asked for and comes back down, like the truth
    assert max(altitudes) == pytest.approx(v.max_altitude_m, abs=0.5)
    assert max(altitudes) == pytest.approx(5.0, abs=0.5)
    assert altitudes[-1] < 0.5
    modes = re.findall(r"Flight mode: (\w+)", out)
    assert modes[modes.index("TAKEOFF") :].count("LAND") == 1 and "-- Landed and disarmed" in out
    assert landed_near(v, 0.0, 0.0, 1.0)


def test_mission_with_progress_then_rtl(harness_run: Fly) -> None:
    run = flown(harness_run, "mission_rtl.py")
    v = run.vehicle(0)
    times = [first_time_near(v, n, e, 2.0) for n, e in ((30, 0), (30, 30), (0, 30))]
    assert None not in times and times == sorted(times), f"waypoints reached at {times}"
    out = run.mission_output(0)
    assert [int(c) for c in re.findall(r"Mission progress: (\d)/3", out)] == [0, 1, 2, 3]
    assert landed_near(v, 0.0, 0.0, 1.5)  # the RTL the script commanded brought it home


def test_raw_mission_round_trip_and_flight(harness_run: Fly) -> None:
    run = flown(harness_run, "mission_raw.py")
    assert "-- Downloaded 4 items, identical: True" in run.mission_output(0)
    v = run.vehicle(0)
    t1, t2 = first_time_near(v, 25, 0, 1.5), first_time_near(v, 25, -20, 1.5)
    assert t1 is not None and t2 is not None and t1 < t2
    assert v.altitude_at(t2) == pytest.approx(12.0, abs=1.0)  # the second waypoint's altitude
    assert landed_near(v, 25.0, -20.0, 1.0)  # the raw NAV_LAND item's position


def test_offboard_velocity_ned_then_body(harness_run: Fly) -> None:
    v = flown(harness_run, "offboard_velocity.py").vehicle(0)
    n, e, _ = v.final_position_ned_m
    assert n == pytest.approx(8.0, abs=1.5)  # 2 m/s north for 4 s (NED frame)
    assert e == pytest.approx(10.0, abs=1.5)  # "forward" 2 m/s for 5 s while facing east (body frame)
    # during the body-frame leg the vehicle faced east: yaw ~ 90 degrees while it moved east
    moving_east = [
        yaw
        for (t, _, _, yaw), m in zip(v.attitudes_deg(), v.track, strict=True)
        if m["vel_ned_m_s"][1] > 1.5 and -m["pos_ned_m"][2] > 5
    ]
    assert len(moving_east) > 50 and statistics.median(moving_east) == pytest.approx(90.0, abs=5.0)
    assert v.landed


def test_offboard_attitude(harness_run: Fly) -> None:
    v = flown(harness_run, "offboard_attitude.py").vehicle(0)
    att = v.attitudes_deg()
    airborne = {m["t_s"] for m in v.track if -m["pos_ned_m"][2] > 5}
    below = [(t, pitch) for t, _, pitch, _ in att if t in airborne and pitch < -6.0]
    nose_down = below[:1]  # the first contiguous stretch (later ones: the hold mode braking after offboard)
    for a, b in itertools.pairwise(below):
        if b[0] - a[0] > 0.1:
            break
        nose_down.append(b)
    duration = nose_down[-1][0] - nose_down[0][0]
    assert 1.5 < duration < 3.0, f"pitched down for {duration:.2f} s, asked for 2 s"
    assert statistics.median(p for _, p in nose_down) == pytest.approx(-10.0, abs=2.0)
    during = [m for m in v.track if nose_down[0][0] <= m["t_s"] <= nose_down[-1][0]]
    assert max(m["vel_ned_m_s"][0] for m in during) > 2.0  # nose down accelerates it north
    assert max(abs(r) for t, r, _, _ in att if t in airborne) < 8.0  # no roll was asked for
    assert 9.0 < v.max_altitude_m < 12.0 and v.landed


def test_orbit_circles_the_point_facing_it(harness_run: Fly) -> None:
    v = flown(harness_run, "orbit.py").vehicle(0)
    centre = (20.0, 0.0)
    start = first_time_near(v, centre[0] - 10.0, 0.0, 30.0)
    samples = []
    for (t, _, _, yaw), m in zip(v.attitudes_deg(), v.track, strict=True):
        n, e, d = m["pos_ned_m"]
        r = math.hypot(n - centre[0], e - centre[1])
        if start is not None and t > start and 8.0 < r < 12.0 and 9.0 < -d < 11.0:
            samples.append((t, r, math.atan2(e - centre[1], n - centre[0]), yaw))
    # the orbit proper: from the first time on the circle until the RTL leaves it
    on_circle = [s for s in samples if abs(s[1] - 10.0) < 1.5]
    assert len(on_circle) > 30 * 50, "less than 30 s of orbit recorded (50 Hz samples)"
    radii = [s[1] for s in on_circle[250:]]  # after the first 5 s (50 Hz samples) of settling onto the circle
    assert statistics.mean(radii) == pytest.approx(10.0, abs=0.5) and max(abs(r - 10.0) for r in radii) < 1.3
    swept = sum(abs(math.remainder(b[2] - a[2], 2 * math.pi)) for a, b in itertools.pairwise(on_circle))
    assert swept > 2.5 * math.pi, f"swept only {math.degrees(swept):.0f} degrees around the centre"
    # facing the centre: heading = bearing from the vehicle to the centre
    settled = on_circle[250:]
    errors = [
        abs(math.remainder(math.radians(yaw) - (bearing + math.pi), 2 * math.pi)) for _, _, bearing, yaw in settled
    ]
    assert statistics.median(math.degrees(x) for x in errors) < 10.0
    assert landed_near(v, 0.0, 0.0, 1.5)


def test_geofence_breach_turns_the_vehicle_back(harness_run: Fly) -> None:
    run = flown(harness_run, "geofence.py")
    v = run.vehicle(0)
    furthest = max(m["pos_ned_m"][0] for m in v.track)
    assert 20.0 < furthest < 30.0, f"went {furthest:.1f} m north: the 20 m fence should turn it back"
    assert "Flight mode: RETURN_TO_LAUNCH" in run.mission_output(0)
    assert landed_near(v, 0.0, 0.0, 1.5)


def test_list_all_parameters_and_set_one(harness_run: Fly) -> None:
    out = flown(harness_run, "params.py").mission_output(0)
    ints = sum(1 for d in PARAM_DEFS if d.type == ParamType.INT32)
    assert f"-- {ints} int and {len(PARAM_DEFS) - ints} float parameters" in out
    listed = {line.split(":")[0] for line in out.splitlines() if not line.startswith("--")}
    assert listed == {d.name for d in PARAM_DEFS}
    assert "-- MPC_XY_VEL_MAX is now 8.0" in out


def test_firmware_version(harness_run: Fly) -> None:
    out = flown(harness_run, "firmware_version.py").mission_output(0)
    major, minor, patch = (
        (FLIGHT_SW_VERSION >> 24) & 0xFF,
        (FLIGHT_SW_VERSION >> 16) & 0xFF,
        (FLIGHT_SW_VERSION >> 8) & 0xFF,
    )
    assert f"Flight software: {major}.{minor}.{patch}" in out
    assert "flight_sw_version_type: RELEASE" in out
