"""Flight modes, commands and failsafes in closed loop with the small test quad model (fast).

The acceptance figures are measured on the real FDM in ``test_acceptance.py``; these tests pin down the
behaviour of every mode and failsafe quickly.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from harness.autopilot.api import (
    FlightMode,
    LandedState,
    MavFrame,
    MissionItem,
    OffboardSetpoint,
    Result,
)
from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.core.clock import ManualClock
from tests.autopilot.quadsim import QuadSim, fly


class Rig:
    def __init__(self, seed: int = 1, gps_fix: int = 3, **params: float) -> None:
        self.sim = QuadSim(np.random.default_rng(seed), gps_fix=gps_fix)
        self.clock = ManualClock()
        self.ap = Autopilot(AutopilotConfig(params=params), wall_clock=self.clock)
        self.run(2.0)

    def run(self, seconds: float) -> list[tuple[int, tuple]]:
        return fly(self.ap, self.sim, seconds, self.clock)

    def run_until(self, cond, limit_s: float, step_s: float = 0.1) -> float:  # type: ignore[no-untyped-def]
        t = 0.0
        while t < limit_s:
            if cond():
                return t
            self.run(step_s)
            t += step_s
        raise AssertionError(f"condition not met within {limit_s} s: {self.ap.telemetry.state()}")

    def up(self, alt: float = 10.0) -> None:
        assert self.ap.action.arm().ok
        assert self.ap.action.takeoff(alt).ok
        self.run_until(lambda: self.ap.telemetry.state().mode == FlightMode.HOLD, 20.0)

    def geo(self, n: float, e: float) -> tuple[int, int]:
        lat, lon, _ = self.sim.ref.to_geo(n, e, 0.0)
        return round(lat * 1e7), round(lon * 1e7)

    def texts(self) -> list[str]:
        return [t.text for t in self.ap.telemetry.pop_status_texts()]


def test_arming_refused_without_gps_fix_with_reason() -> None:
    rig = Rig(gps_fix=1)
    r = rig.ap.action.arm()
    assert r.result == Result.DENIED and "GPS" in r.reason
    assert any("Arming denied" in t for t in rig.texts())
    assert not rig.ap.telemetry.state().armed and not rig.ap.telemetry.state().health.preflight_ok
    assert rig.ap.action.arm(force=True).ok  # force overrides the checks


def test_takeoff_then_hold_then_land_and_disarm() -> None:
    rig = Rig()
    assert rig.ap.telemetry.state().health.preflight_ok
    rig.up(8.0)
    s = rig.ap.telemetry.state()
    assert s.landed_state == LandedState.IN_AIR and abs(rig.sim.pos[2] + 8.0) < 0.3
    r = rig.ap.action.disarm()
    assert r.result == Result.DENIED and "in air" in r.reason
    assert rig.ap.action.land().ok
    rig.run(1.0)
    assert rig.ap.telemetry.state().landed_state == LandedState.LANDING
    rig.run_until(lambda: not rig.ap.telemetry.state().armed, 30.0)
    assert rig.sim.on_ground and math.hypot(rig.sim.pos[0], rig.sim.pos[1]) < 0.5
    assert "Landing detected" in rig.texts()


def test_refusals_carry_reasons() -> None:
    rig = Rig()
    assert rig.ap.action.takeoff(math.inf).result == Result.DENIED
    assert rig.ap.action.set_mode(FlightMode.MANUAL).result == Result.DENIED
    assert rig.ap.action.set_mode(FlightMode.MISSION).result == Result.DENIED
    assert rig.ap.action.set_mode(FlightMode.OFFBOARD).result == Result.DENIED
    assert rig.ap.action.orbit(10.0, 2.0).result == Result.TEMPORARILY_REJECTED
    assert rig.ap.action.change_speed(math.nan).result == Result.DENIED
    assert rig.ap.offboard.set_setpoint(OffboardSetpoint(velocity_m_s=(math.nan, 0.0, 0.0))).result == Result.DENIED


def test_return_to_launch_from_away() -> None:
    rig = Rig(RTL_RETURN_ALT=15.0)
    rig.up(5.0)
    lat, lon = rig.geo(30.0, 10.0)
    assert rig.ap.action.reposition(lat * 1e-7, lon * 1e-7, None).ok
    rig.run_until(lambda: math.hypot(rig.sim.pos[0] - 30.0, rig.sim.pos[1] - 10.0) < 0.5, 30.0)
    assert rig.ap.action.return_to_launch().ok
    rig.run(4.0)
    assert rig.sim.pos[2] < -12.0  # climbed towards RTL_RETURN_ALT first
    rig.run_until(lambda: not rig.ap.telemetry.state().armed, 80.0)
    assert math.hypot(rig.sim.pos[0], rig.sim.pos[1]) < 1.0


def test_offboard_velocity_and_setpoint_loss_to_hold() -> None:
    rig = Rig()
    rig.up(5.0)
    ap = rig.ap
    sp = OffboardSetpoint(velocity_m_s=(2.0, 0.0, 0.0), yaw_rad=0.0)
    assert ap.offboard.set_setpoint(sp).ok
    assert ap.action.set_mode(FlightMode.OFFBOARD).ok
    for _ in range(40):  # stream for 4 s
        ap.offboard.set_setpoint(sp)
        rig.run(0.1)
    assert abs(rig.sim.vel[0] - 2.0) < 0.3 and ap.telemetry.state().mode == FlightMode.OFFBOARD
    lost_at = rig.clock.now_ns()
    rig.run_until(lambda: ap.telemetry.state().mode == FlightMode.HOLD, 2.0, 0.02)
    assert (rig.clock.now_ns() - lost_at) * 1e-9 <= 1.0
    assert ap.telemetry.state().failsafe == "offboard_loss"
    rig.run(6.0)
    assert math.hypot(*rig.sim.vel[:2]) < 0.3  # braked and holding


def test_geofence_breach_returns() -> None:
    rig = Rig(GF_MAX_HOR_DIST=20.0, RTL_RETURN_ALT=10.0)
    rig.up(5.0)
    lat, lon = rig.geo(40.0, 0.0)
    assert rig.ap.action.reposition(lat * 1e-7, lon * 1e-7, None).ok
    rig.run_until(lambda: rig.ap.telemetry.state().mode == FlightMode.RTL, 20.0)
    assert rig.ap.telemetry.state().failsafe == "geofence"
    assert 18.0 < rig.sim.pos[0] < 26.0
    assert any("Geofence" in t for t in rig.texts())


def test_low_battery_returns_then_critical_lands() -> None:
    rig = Rig(SIM_BAT_DRAIN=200.0, RTL_RETURN_ALT=10.0)
    rig.up(5.0)
    rig.run_until(lambda: rig.ap.telemetry.state().mode == FlightMode.RTL, 60.0)
    s = rig.ap.telemetry.state()
    assert s.failsafe == "battery" and s.battery.remaining < 0.15
    rig.run_until(lambda: rig.ap.telemetry.state().mode == FlightMode.LAND, 60.0)
    assert rig.ap.telemetry.state().failsafe == "battery_critical"


@pytest.mark.parametrize("speed", [3.0])
def test_mission_items_reached_in_order(speed: float) -> None:
    rig = Rig()
    ap = rig.ap

    def item(seq: int, cmd: int, n: float = 0.0, e: float = 0.0, alt: float = 6.0, **kw: float) -> MissionItem:
        lat, lon = rig.geo(n, e)
        return MissionItem(seq, MavFrame.GLOBAL_RELATIVE_ALT_INT, cmd, x=lat, y=lon, z=alt, **kw)  # type: ignore[arg-type]

    items = [
        item(0, 22),
        item(1, 178, param2=speed),
        item(2, 16, 15.0, 0.0),
        item(3, 2000),
        item(4, 19, 15.0, 10.0, param1=2.0),
        item(5, 93, param1=1.0),
        item(6, 21, 0.0, 10.0, 0.0),
    ]
    assert ap.mission.upload(items).ok
    assert ap.action.arm().ok and ap.mission.start().ok
    rig.run_until(lambda: not ap.telemetry.state().armed, 120.0)
    reached = [r.seq for r in ap.telemetry.pop_mission_reached()]
    assert reached == list(range(7))
    assert ap.telemetry.state().mission.finished
    assert math.hypot(rig.sim.pos[0], rig.sim.pos[1] - 10.0) < 1.0


def test_orbit_keeps_radius() -> None:
    rig = Rig()
    rig.up(5.0)
    lat, lon = rig.geo(10.0, 0.0)
    assert rig.ap.action.orbit(8.0, 3.0, lat * 1e-7, lon * 1e-7, None).ok
    rig.run(10.0)
    radii = []
    for _ in range(20):
        rig.run(0.5)
        radii.append(math.hypot(rig.sim.pos[0] - 10.0, rig.sim.pos[1]))
    assert all(abs(r - 8.0) < 1.0 for r in radii)
    assert rig.ap.telemetry.state().mode == FlightMode.ORBIT


def test_offboard_position_body_velocity_and_attitude() -> None:
    from harness.autopilot.api import AttitudeTarget, OffboardFrame
    from harness.core.geo import quat_from_euler

    rig = Rig()
    ap = rig.ap
    assert ap.action.arm().ok
    # from the ground, as MAVSDK's offboard examples do: a setpoint first, then the mode, then climb
    sp = OffboardSetpoint(position_m=(0.0, 0.0, -6.0), yaw_rad=math.pi / 2)
    assert ap.offboard.set_setpoint(sp).ok and ap.action.set_mode(FlightMode.OFFBOARD).ok

    def stream(s: OffboardSetpoint | AttitudeTarget, seconds: float) -> None:
        for _ in range(round(seconds * 10)):
            if isinstance(s, OffboardSetpoint):
                ap.offboard.set_setpoint(s)
            else:
                ap.offboard.set_attitude(s)
            rig.run(0.1)

    stream(sp, 10.0)
    assert abs(rig.sim.pos[2] + 6.0) < 0.3 and ap.telemetry.state().landed_state == LandedState.IN_AIR
    assert abs(ap.telemetry.state().yaw_rad - math.pi / 2) < 0.1
    # body-frame velocity: forward while facing east = east
    stream(OffboardSetpoint(velocity_m_s=(2.0, 0.0, 0.0), frame=OffboardFrame.BODY_NED), 4.0)
    assert abs(rig.sim.vel[1] - 2.0) < 0.3 and abs(rig.sim.vel[0]) < 0.3
    stream(OffboardSetpoint(velocity_m_s=(0.0, 0.0, 0.0)), 3.0)
    # acceleration only: 1 m/s² north for 2 s
    v0 = rig.sim.vel[0]
    stream(OffboardSetpoint(accel_m_s2=(1.0, 0.0, 0.0)), 2.0)
    assert 1.4 < rig.sim.vel[0] - v0 < 2.6
    stream(OffboardSetpoint(velocity_m_s=(0.0, 0.0, 0.0)), 4.0)
    # attitude: 10 degrees of roll at hover thrust, facing east, accelerates south
    x0 = rig.sim.pos[0]
    stream(AttitudeTarget(quat_from_euler(math.radians(10.0), 0.0, math.pi / 2), 0.5), 2.0)
    assert rig.sim.pos[0] < x0 - 1.0
    assert abs(ap.telemetry.state().roll_rad - math.radians(10.0)) < math.radians(3.0)


def test_hover_thrust_estimate_corrects_a_wrong_parameter() -> None:
    rig = Rig(MPC_THR_HOVER=0.35)  # the test quad hovers at 0.5
    rig.up(6.0)
    rig.run(10.0)
    assert abs(rig.ap.core.hover_thrust - 0.5) < 0.03
    assert abs(rig.sim.pos[2] + 6.0) < 0.3
