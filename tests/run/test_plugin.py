"""The pytest plugin as a user would use it: fly a mission in a test and assert on the recording."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from harness.pytest_plugin import RunRecord

pytestmark = pytest.mark.sim
MISSIONS = Path(__file__).resolve().parents[2] / "missions"


def test_hover_mission_through_the_fixture(harness_run: Callable[..., RunRecord]) -> None:
    run = harness_run(mission=MISSIONS / "hover.py", vehicles=1, args=["10"])
    assert run.ok, run.message
    v = run.vehicle(0)
    assert v.mission_exit_code == 0 and v.landed and not v.crashed
    assert 9.7 < v.max_altitude_m < 10.5
    # while hovering (takeoff done, landing not yet begun) it holds 10 m
    track = [m for m in v.track if m["pos_ned_m"][2] < -9.5]
    t_mid = (track[0]["t_s"] + track[-1]["t_s"]) / 2
    assert v.altitude_at(t_mid) == pytest.approx(10.0, abs=0.5)
    assert v.distance_from_start_m() < 1.5
