"""Failure injection, stick modes and follow target in closed loop (small test quad; the motor failure on the
real JSBSim FDM): what the vehicle does, not only what the commands answer."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import pytest

from harness.autopilot.api import FlightMode, LandedState, Result
from harness.autopilot.failures import FailureType, FailureUnit
from harness.autopilot.manual import deadzone
from tests.autopilot.rig import FlightRig
from tests.autopilot.test_modes import Rig

GPS, OFF, OK = FailureUnit.SENSOR_GPS, FailureType.OFF, FailureType.OK


def _sticks(rig: Rig, x: int = 0, y: int = 0, z: int = 500, r: int = 0) -> None:
    assert rig.ap.manual_control.set_sticks(x, y, z, r).ok


def _fly_with_sticks(rig: Rig, seconds: float, **axes: int) -> None:
    """Sticks held for ``seconds``, resent every 0.1 s as a joystick does."""
    for _ in range(round(seconds * 10)):
        _sticks(rig, **axes)
        rig.run(0.1)


# ---------------------------------------------------------------------------------------- failure injection
def test_gps_off_dead_reckons_then_descends_and_gps_back_restores_position() -> None:
    rig = Rig()
    rig.up(15.0)
    assert rig.ap.failure.inject(GPS, OFF, 0).ok
    rig.run(2.0)
    s = rig.ap.telemetry.state()
    assert not s.health.gps_ok and s.health.local_position_ok  # dead reckoning, EKF2_NOAID_TOUT = 5 s
    assert s.mode == FlightMode.HOLD
    assert rig.ap.action.set_mode(FlightMode.MISSION).result == Result.DENIED  # no mission anyway; HOLD stays
    rig.run_until(lambda: rig.ap.telemetry.state().mode == FlightMode.LAND, 5.0)
    texts = rig.texts()
    assert any("position estimate invalid" in t for t in texts) and any("Failsafe" in t for t in texts)
    assert rig.ap.telemetry.state().failsafe == "navigation"
    # Descend: straight down at the land speeds, no position hold, refuses position modes
    assert rig.ap.action.hold().result == Result.DENIED
    z0 = rig.sim.pos[2]
    rig.run(3.0)
    assert rig.sim.pos[2] - z0 > 2.0, "not descending"
    assert rig.ap.failure.inject(GPS, OK, 0).ok
    rig.run_until(lambda: rig.ap.telemetry.state().health.local_position_ok, 3.0)
    rig.run_until(lambda: not rig.ap.telemetry.state().armed, 60.0)  # lands and disarms
    assert rig.sim.pos[2] > -0.3


def test_gps_stuck_mag_and_baro_off_show_in_health() -> None:
    rig = Rig()
    rig.up(5.0)
    assert rig.ap.failure.inject(FailureUnit.SENSOR_MAG, OFF, 0).ok
    assert rig.ap.failure.inject(FailureUnit.SENSOR_BARO, OFF, 1).ok
    rig.run(3.0)
    h = rig.ap.telemetry.state().health
    assert not h.mag_ok and not h.baro_ok and h.gps_fix_ok and h.gyro_ok
    assert rig.ap.telemetry.state().mode == FlightMode.HOLD  # no failsafe for those (PX4 warns, keeps flying)
    assert rig.ap.failure.inject(GPS, FailureType.STUCK, 0).ok
    rig.run(0.5)
    lat = rig.ap.telemetry.state().gps.lat_deg
    rig.run(1.0)
    assert (
        rig.ap.telemetry.state().gps.lat_deg == lat and rig.ap.telemetry.state().gps.fix_type == 3
    )  # the same fix, repeated
    assert rig.ap.failure.inject(FailureUnit.SENSOR_GYRO, OFF, 0).ok
    assert not rig.ap.telemetry.state().health.gyro_ok and rig.ap.telemetry.state().health.accel_ok


def test_battery_failure_empties_it_and_lands() -> None:
    rig = Rig()
    rig.up(10.0)
    assert rig.ap.failure.inject(FailureUnit.SYSTEM_BATTERY, OFF, 0).ok
    rig.run(0.5)
    s = rig.ap.telemetry.state()
    assert s.battery.remaining == 0.0 and s.mode == FlightMode.LAND and s.failsafe == "battery_critical"
    rig.run_until(lambda: not rig.ap.telemetry.state().armed, 60.0)


def test_unsupported_and_invalid_failures_are_refused() -> None:
    rig = Rig()
    assert rig.ap.failure.inject(FailureUnit.SENSOR_AIRSPEED, OFF, 0).result == Result.UNSUPPORTED
    assert rig.ap.failure.inject(GPS, FailureType.GARBAGE, 0).result == Result.UNSUPPORTED
    assert rig.ap.failure.inject(77, OFF, 0).result == Result.DENIED
    assert rig.ap.failure.inject(FailureUnit.SYSTEM_MOTOR, OFF, 9).result == Result.DENIED


def test_motor_off_the_fdm_flies_on_three_motors_and_comes_down(fdm: Callable[..., Any]) -> None:
    rig = FlightRig(fdm())
    rig.up(20.0)
    assert rig.ap.failure.inject(FailureUnit.SYSTEM_MOTOR, OFF, 1).ok
    rig.run(0.5)
    assert rig.ap.telemetry.state().motors[0] == 0.0 and max(rig.ap.telemetry.state().motors) > 0.3
    rig.run(6.0)
    assert -rig.pos[2] < 10.0, f"still at {-rig.pos[2]:.1f} m: the FDM did not lose the motor"


# ---------------------------------------------------------------------------------------- sticks
def test_deadzone() -> None:
    assert deadzone(0.05, 0.1) == 0.0 and deadzone(1.0, 0.1) == 1.0 and deadzone(-0.55, 0.1) == pytest.approx(-0.5)


def test_stick_modes_refused_without_input_then_fly_with_sticks() -> None:
    rig = Rig()
    rig.up(10.0)
    for mode in (FlightMode.POSCTL, FlightMode.ALTCTL, FlightMode.STABILIZED, FlightMode.MANUAL):
        r = rig.ap.action.set_mode(mode)
        assert r.result == Result.DENIED and "manual control" in r.reason
    _sticks(rig)
    assert rig.ap.action.set_mode(FlightMode.POSCTL).ok
    start = tuple(rig.sim.pos)
    _fly_with_sticks(rig, 4.0, x=1000)  # full forward: north (facing north) at up to MPC_VEL_MANUAL
    n = rig.sim.pos[0] - start[0]
    assert n > 15.0 and abs(rig.sim.pos[1] - start[1]) < 2.0 and abs(rig.sim.pos[2] - start[2]) < 1.0
    _fly_with_sticks(rig, 4.0)  # centred: brake and hold
    held = tuple(rig.sim.pos)
    _fly_with_sticks(rig, 3.0)
    assert math.dist(held, rig.sim.pos) < 0.5
    _fly_with_sticks(rig, 2.0, z=1000)  # full throttle: climb at MPC_Z_VEL_MAX_UP
    assert held[2] - rig.sim.pos[2] > 3.0
    assert rig.ap.action.set_mode(FlightMode.STABILIZED).ok
    _fly_with_sticks(rig, 1.0, y=600)  # roll right: accelerates east
    assert rig.sim.vel[1] > 2.0


def test_rc_loss_in_position_mode_holds_and_nav_rcl_act_returns() -> None:
    rig = Rig(NAV_RCL_ACT=2)
    rig.up(10.0)
    _sticks(rig)
    assert rig.ap.action.set_mode(FlightMode.POSCTL).ok
    _fly_with_sticks(rig, 1.0)
    rig.run(1.0)  # COM_RC_LOSS_T = 0.5 s
    assert rig.ap.telemetry.state().mode == FlightMode.RTL and rig.ap.telemetry.state().failsafe == "rc_loss"
    assert any("Manual control lost" in t for t in rig.texts())


# ---------------------------------------------------------------------------------------- follow target
def test_follow_target_keeps_distance_behind_the_moving_target() -> None:
    rig = Rig(FLW_TGT_DST=6.0, FLW_TGT_HT=8.0, FLW_TGT_FA=180.0, FLW_TGT_RS=0.0)
    assert rig.ap.action.set_mode(FlightMode.FOLLOW_TARGET).result == Result.DENIED  # on the ground
    rig.up(5.0)
    assert rig.ap.action.set_mode(FlightMode.FOLLOW_TARGET).ok
    ref = rig.sim.ref
    n = 10.0
    for _ in range(150):  # the target walks north at 2 m/s, reported at 10 Hz
        lat, lon, alt = ref.to_geo(n, 0.0, 0.0)
        assert rig.ap.follow_me.set_target(lat, lon, alt, (2.0, 0.0, 0.0)).ok
        rig.run(0.1)
        n += 0.2
    p = rig.sim.pos
    assert abs(p[1]) < 1.0 and (n - 0.2) - p[0] == pytest.approx(6.0, abs=1.5)  # behind it
    assert -p[2] == pytest.approx(8.0, abs=1.0)  # FLW_TGT_HT above home
    s = rig.ap.telemetry.state()
    assert abs(math.remainder(s.yaw_rad, math.tau)) < 0.3  # nose on the target (north)
    rig.run(4.0)  # the target stops reporting: hold
    assert rig.ap.telemetry.state().mode == FlightMode.FOLLOW_TARGET and math.hypot(*rig.sim.vel[:2]) < 0.5
    assert rig.ap.telemetry.state().landed_state == LandedState.IN_AIR


def test_gps_loss_in_position_mode_degrades_to_altitude_mode() -> None:
    rig = Rig()
    rig.up(10.0)
    _sticks(rig)
    assert rig.ap.action.set_mode(FlightMode.POSCTL).ok
    assert rig.ap.failure.inject(GPS, OFF, 0).ok
    _fly_with_sticks(rig, 7.0)  # EKF2_NOAID_TOUT 5 s of dead reckoning, then no position
    s = rig.ap.telemetry.state()
    assert s.mode == FlightMode.ALTCTL and s.failsafe == "navigation"  # COM_POSCTL_NAVL 0, sticks live
    z = rig.sim.pos[2]
    _fly_with_sticks(rig, 3.0)
    assert abs(rig.sim.pos[2] - z) < 1.0  # the altitude is still held (baro)
    assert rig.ap.action.set_mode(FlightMode.POSCTL).result == Result.DENIED


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gps_off_on_the_fdm_descends_with_bounded_drift(fdm: Callable[..., Any], seed: int) -> None:
    """GPS off at 22 m on JSBSim: 5 s of dead reckoning, then Descend; the drift is what dead reckoning built."""
    rig = FlightRig(fdm(seed))
    rig.up(5.0)
    assert rig.ap.action.reposition(None, None, rig.ap.telemetry.state().alt_amsl_m + 17.0).ok
    rig.run(8.0)
    p0 = rig.pos
    assert rig.ap.failure.inject(GPS, OFF, 0).ok
    rig.run(15.0)
    drift = math.dist(p0[:2], rig.pos[:2])
    print(f"seed {seed}: drift {drift:.1f} m 15 s after GPS off, altitude {-p0[2]:.1f} -> {-rig.pos[2]:.1f} m")
    assert rig.ap.telemetry.state().mode == FlightMode.LAND and -rig.pos[2] < -p0[2] - 10.0
    assert drift < 6.0
