"""The gimbal service in lockstep: it moves with ``Autopilot.step`` at 90 deg/s from the sim time of its first
setpoint, reports (pitch, yaw relative to the heading) in the tick's status once used and nothing before,
holds a locked yaw in the earth frame, tracks a region of interest, refuses what is not finite; the ArduCopter
personality has none."""

from __future__ import annotations

import math

import numpy as np
import pytest

from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.autopilot.mavlink.ardupilot.adapter import CopterSystem
from harness.autopilot.mavlink.ardupilot.params import CopterParams
from harness.wire import protocol as p
from tests.autopilot.quadsim import QuadSim


class _Flown:
    def __init__(self) -> None:
        self.sim = QuadSim(np.random.default_rng(3))
        self.ap = Autopilot(AutopilotConfig())
        self.frame = self.sim.frame()

    def step_s(self, seconds: float) -> None:
        for _ in range(round(seconds * 1e9 / self.sim.tick_ns)):
            self.frame = self.sim.step(self.ap.step(self.frame))

    def heading_deg(self) -> float:
        return math.degrees(self.ap.core.est.yaw)


@pytest.fixture
def flown() -> _Flown:
    f = _Flown()
    f.step_s(12.0)  # GPS and the estimate settled
    return f


def test_an_unused_gimbal_reports_nothing_and_stays(flown: _Flown) -> None:
    ap = flown.ap
    assert ap.tick_status()[4] is None and not ap.gimbal.used
    assert p.pack_status(*ap.tick_status()) < p.STATUS_GIMBAL  # the status of a vehicle without gimbals
    assert ap.gimbal.set_angles(math.nan, 10.0).reason == "gimbal: angles must be finite"
    assert ap.gimbal.set_rates(math.inf, 0.0).reason == "gimbal: rates must be finite"
    assert ap.gimbal.point_at(91.0, 8.0, 400.0).reason.startswith("ROI")
    flown.step_s(0.5)
    assert ap.tick_status()[4] is None and not ap.gimbal.used


def test_angles_are_reached_at_the_slew_rate_from_the_setpoints_sim_time(flown: _Flown) -> None:
    ap = flown.ap
    assert ap.gimbal.set_angles(-30.0, 45.0).ok
    assert ap.tick_status()[4] == (0.0, 0.0)  # used from now: reported before it moves
    flown.step_s(0.2)
    pitch, yaw = ap.tick_status()[4]  # type: ignore[misc]
    assert pitch == pytest.approx(-18.0, abs=1e-9) and yaw == pytest.approx(18.0, abs=1e-9)
    att = ap.gimbal.attitude()
    assert att.pitch_rate_deg_s == pytest.approx(-90.0) and att.yaw_rate_deg_s == pytest.approx(90.0)
    flown.step_s(0.4)
    assert ap.tick_status()[4] == (-30.0, 45.0)
    assert p.unpack_gimbal(p.pack_status(*ap.tick_status())) == (-30.0, 45.0)
    assert ap.gimbal.set_rates(10.0, 0.0).ok  # 10 deg/s up for 1 s
    flown.step_s(1.0)
    assert ap.tick_status()[4] == pytest.approx((-20.0, 45.0), abs=1e-6)


def test_a_locked_yaw_is_held_from_north_and_a_roi_is_tracked(flown: _Flown) -> None:
    ap = flown.ap
    assert ap.gimbal.set_angles(0.0, 100.0, yaw_lock=True).ok
    flown.step_s(3.0)
    _, yaw = ap.tick_status()[4]  # type: ignore[misc]
    assert yaw == pytest.approx(((100.0 - flown.heading_deg() + 180.0) % 360.0) - 180.0, abs=0.01)
    assert ap.gimbal.attitude().yaw_lock
    lat, lon, alt = ap.core.est.geo()
    north_m = 100.0
    assert ap.gimbal.point_at(lat + math.degrees(north_m / 6_378_137.0), lon, alt - 100.0).ok  # 45 deg down, north
    flown.step_s(2.0)
    pitch, yaw = ap.tick_status()[4]  # type: ignore[misc]
    assert pitch == pytest.approx(-45.0, abs=0.1)
    assert yaw == pytest.approx(((0.0 - flown.heading_deg() + 180.0) % 360.0) - 180.0, abs=0.1)


def test_the_ardupilot_personality_has_no_gimbal() -> None:
    core = Autopilot()
    assert CopterSystem(core, CopterParams(core.params, 1)).gimbal is None
