"""Our example missions (MAVSDK-Python style, both APIs) through `harness run`: each exits 0 and the
vehicle did what the script asked, checked in the recording."""

from __future__ import annotations

import math

import pytest

from .flights import Fly, flown

pytestmark = pytest.mark.sim


def closest(track: list[dict[str, object]], n: float, e: float) -> float:
    return min(math.hypot(m["pos_ned_m"][0] - n, m["pos_ned_m"][1] - e) for m in track)  # type: ignore[index]


def test_goto_reaches_the_point_and_returns(harness_run: Fly) -> None:
    v = flown(harness_run, "goto.py").vehicle(0)
    assert closest(v.track, 40.0, 30.0) < 1.5  # the goto target, 40 m north and 30 m east
    arrival = next(m for m in v.track if math.hypot(m["pos_ned_m"][0] - 40, m["pos_ned_m"][1] - 30) < 1.5)
    assert -arrival["pos_ned_m"][2] == pytest.approx(15.0, abs=1.0)  # at the altitude asked for
    assert v.landed and v.distance_from_start_m() < 1.5  # RTL lands at home


def test_survey_visits_every_waypoint_in_order_and_lands_home(harness_run: Fly) -> None:
    run = flown(harness_run, "survey.py")
    v = run.vehicle(0)
    waypoints = [(10, 0), (70, 0), (70, 15), (10, 15), (10, 30), (70, 30)]
    times = []
    for n, e in waypoints:
        near = [m for m in v.track if math.hypot(m["pos_ned_m"][0] - n, m["pos_ned_m"][1] - e) < 2.0]
        assert near, f"waypoint ({n}, {e}) was not reached"
        times.append(near[0]["t_s"])
    assert times == sorted(times)
    assert "Mission progress: 6/6" in run.mission_output(0)
    assert v.landed and v.distance_from_start_m() < 1.5


def test_offboard_position_then_velocity(harness_run: Fly) -> None:
    v = flown(harness_run, "offboard.py").vehicle(0)
    assert closest(v.track, 10.0, 0.0) < 1.0
    n, e, _ = v.final_position_ned_m
    assert n == pytest.approx(10.0, abs=1.5)
    assert e == pytest.approx(10.0, abs=2.5)  # 2 m/s east for 5 s
    assert 9.0 < v.max_altitude_m < 11.0 and v.landed


def test_telemetry_printer_prints_once_per_sim_second(harness_run: Fly) -> None:
    lines = flown(harness_run, "telemetry_printer.py", "3").mission_output(0).splitlines()
    assert len(lines) == 3 and all("mode HOLD" in line for line in lines)


def test_native_api_takeoff_and_land(harness_run: Fly) -> None:
    v = flown(harness_run, "takeoff_and_land_native.py").vehicle(0)
    assert v.max_altitude_m == pytest.approx(2.6, abs=0.4)  # MIS_TAKEOFF_ALT default 2.5 m above the skids
    assert v.landed and v.distance_from_start_m() < 1.0
