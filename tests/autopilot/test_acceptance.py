"""Acceptance of the flight core (issue 4): closed loop in the real FDM with sensor noise on.

Each test prints its measured figures on a line starting with ``FIGURE`` (run with ``-s`` to see them).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest

from harness.autopilot.api import FlightMode, LandedState, MavFrame, MissionItem, OffboardSetpoint, Result
from tests.autopilot.rig import FlightRig, Plant, cross_track_m

pytestmark = pytest.mark.sim

PlantFactory = Callable[..., Plant]


def figure(name: str, **values: float) -> None:
    print("FIGURE", name, " ".join(f"{k}={v:.3f}" for k, v in values.items()))


def _hover_band(rig: FlightRig, seconds: float) -> tuple[float, float, float]:
    """Hover for ``seconds``: max horizontal distance and max vertical deviation from the mean position,
    and the max deviation on any one axis (north, east, down) from the mean position."""
    n0 = len(rig.log)
    rig.run(seconds)
    pts = [p for _, p, _ in rig.log[n0:]]
    mean = [sum(p[i] for p in pts) / len(pts) for i in range(3)]
    h = max(math.hypot(p[0] - mean[0], p[1] - mean[1]) for p in pts)
    v = max(abs(p[2] - mean[2]) for p in pts)
    axis = max(max(abs(p[i] - mean[i]) for i in range(3)) for p in pts)
    return h, v, axis


def test_takeoff_and_hover_still_air(fdm: PlantFactory) -> None:
    rig = FlightRig(fdm())
    assert rig.ap.action.arm().ok, rig.ap.telemetry.arming_check()
    t0 = rig.frame.t_ns * 1e-9
    assert rig.ap.action.takeoff(10.0).ok
    rig.run(15.0)
    alt = [(t - t0, -p[2] + rig.start[2]) for t, p, _ in rig.log if t >= t0]
    overshoot = max(a for _, a in alt) - 10.0
    # time after which the altitude stays within 10 ± 0.3 m
    settle = next(t for i, (t, _) in enumerate(alt) if all(abs(a - 10.0) <= 0.3 for _, a in alt[i:]))
    figure("takeoff", settle_s=settle, overshoot_m=overshoot)
    assert settle <= 10.0 and overshoot < 0.5
    rig.run(5.0)
    h, v, axis = _hover_band(rig, 60.0)
    figure("hover_still_air_60s_default_gps", horizontal_m=h, vertical_m=v, max_axis_m=axis)
    assert axis <= 0.2  # every axis within ±0.2 m of the mean position, with PX4-SITL's GPS error


def test_hover_still_air_standalone_gps(fdm_standalone_gps: PlantFactory) -> None:
    """A standalone receiver's slowly wandering error (σ 0.3 m, τ 20 s): the vehicle follows it, as any
    GPS-based position hold does; the height (baro) keeps the ±0.2 m band."""
    rig = FlightRig(fdm_standalone_gps())
    rig.up(10.0)
    rig.run(5.0)
    h, v, axis = _hover_band(rig, 60.0)
    figure("hover_still_air_60s_standalone_gps", horizontal_m=h, vertical_m=v, max_axis_m=axis)
    assert v <= 0.2 and h <= 1.0


def test_hover_still_air_gps_white_noise(fdm_white_gps: PlantFactory) -> None:
    """The standalone noise level (σ 0.3 m) decorrelating within 0.1 s: what the estimator and control hold."""
    rig = FlightRig(fdm_white_gps())
    rig.up(10.0)
    rig.run(5.0)
    h, v, axis = _hover_band(rig, 60.0)
    figure("hover_still_air_60s_white_gps", horizontal_m=h, vertical_m=v, max_axis_m=axis)
    assert axis <= 0.2


def test_hover_in_wind(fdm_wind: PlantFactory) -> None:
    rig = FlightRig(fdm_wind())
    rig.up(10.0)
    rig.run(10.0)
    h, v, axis = _hover_band(rig, 60.0)
    figure("hover_wind_5ms_light_turbulence_60s", horizontal_m=h, vertical_m=v, max_axis_m=axis)
    assert axis <= 1.0


def test_square_mission(fdm: PlantFactory) -> None:
    rig = FlightRig(fdm())
    ap = rig.ap
    corners = [(0.0, 0.0), (50.0, 0.0), (50.0, 50.0), (0.0, 50.0), (0.0, 0.0)]

    def item(seq: int, cmd: int, n: float = 0.0, e: float = 0.0, alt: float = 10.0, **kw: float) -> MissionItem:
        lat, lon = rig.geo(n, e)
        return MissionItem(seq, MavFrame.GLOBAL_RELATIVE_ALT_INT, cmd, x=lat, y=lon, z=alt, **kw)  # type: ignore[arg-type]

    items = [item(0, 22), item(1, 178, param2=5.0)]
    items += [item(2 + i, 16, n, e) for i, (n, e) in enumerate(corners[1:])]
    items.append(item(len(items), 21, 0.0, 0.0, 0.0))
    assert ap.mission.upload(items).ok
    assert ap.action.arm().ok and ap.mission.start().ok
    reached: list[tuple[int, float]] = []

    def collect() -> None:
        reached.extend((r.seq, r.t_ns * 1e-9) for r in ap.telemetry.pop_mission_reached())

    rig.on_tick = collect
    rig.run_until(lambda: not ap.telemetry.state().armed, 200.0)
    collect()
    seqs = [s for s, _ in reached]
    assert seqs == list(range(len(items)))
    t_reach = dict(reached)
    # cross-track error on each 50 m leg, between leaving one corner and reaching the next
    errs = []
    for leg in range(4):
        t_a, t_b = t_reach[1 + leg], t_reach[2 + leg]
        a, b = corners[leg], corners[leg + 1]
        for t, p, _ in rig.log:
            if t_a <= t <= t_b:
                errs.append(cross_track_m((p[0] - rig.start[0], p[1] - rig.start[1]), a, b))
    rms = math.sqrt(sum(e * e for e in errs) / len(errs))
    land = math.hypot(rig.pos[0], rig.pos[1])
    figure("square_mission", cross_track_rms_m=rms, cross_track_max_m=max(errs), land_error_m=land)
    assert rms < 1.0 and land < 1.0
    assert not ap.telemetry.state().armed and ap.telemetry.state().landed_state == LandedState.ON_GROUND


def test_return_from_100m(fdm: PlantFactory) -> None:
    rig = FlightRig(fdm())
    rig.up(10.0)
    lat, lon = rig.geo(80.0, 60.0)
    assert rig.ap.action.reposition(lat * 1e-7, lon * 1e-7, None).ok
    rig.run_until(lambda: math.hypot(rig.pos[0] - 80.0, rig.pos[1] - 60.0) < 1.0, 60.0)
    assert rig.ap.action.return_to_launch().ok
    rig.run_until(lambda: not rig.ap.telemetry.state().armed, 150.0)
    err = math.hypot(rig.pos[0], rig.pos[1])
    figure("return_100m", land_error_m=err)
    assert err < 1.5


def test_offboard_velocity_step(fdm: PlantFactory) -> None:
    rig = FlightRig(fdm())
    rig.up(10.0)
    ap = rig.ap
    sp = OffboardSetpoint(velocity_m_s=(0.0, 0.0, 0.0), yaw_rad=0.0)
    ap.offboard.set_setpoint(sp)
    assert ap.action.set_mode(FlightMode.OFFBOARD).ok
    current = [sp]
    rig.on_tick = lambda: ap.offboard.set_setpoint(current[0])  # streamed, as MAVSDK does
    rig.run(3.0)
    current[0] = OffboardSetpoint(velocity_m_s=(3.0, 0.0, 0.0), yaw_rad=0.0)
    n0 = len(rig.log)
    rig.run(6.0)
    t0 = rig.log[n0][0]
    v = [(t - t0, vel[0]) for t, _, vel in rig.log[n0:]]
    t10 = next(t for t, x in v if x >= 0.3)
    t90 = next(t for t, x in v if x >= 2.7)
    overshoot = (max(x for _, x in v) - 3.0) / 3.0
    figure("offboard_velocity_step", rise_s=t90 - t10, overshoot=overshoot)
    assert t90 - t10 < 1.5 and overshoot < 0.15


def test_failsafe_low_battery_returns(fdm: PlantFactory) -> None:
    rig = FlightRig(fdm(), SIM_BAT_DRAIN=150.0)
    rig.up(5.0)
    lat, lon = rig.geo(20.0, 0.0)
    rig.ap.action.reposition(lat * 1e-7, lon * 1e-7, None)
    rig.run_until(lambda: rig.ap.telemetry.state().mode == FlightMode.RTL, 120.0)
    s = rig.ap.telemetry.state()
    figure("failsafe_low_battery", remaining=s.battery.remaining, voltage_v=s.battery.voltage_v)
    assert s.failsafe == "battery" and s.battery.remaining < 0.15


def test_failsafe_setpoint_loss_holds_within_1s(fdm: PlantFactory) -> None:
    rig = FlightRig(fdm())
    rig.up(5.0)
    ap = rig.ap
    sp = OffboardSetpoint(velocity_m_s=(1.0, 0.0, 0.0))
    ap.offboard.set_setpoint(sp)
    assert ap.action.set_mode(FlightMode.OFFBOARD).ok
    rig.on_tick = lambda: ap.offboard.set_setpoint(sp)
    rig.run(3.0)
    rig.on_tick = None
    lost = rig.clock.now_ns()
    rig.run_until(lambda: ap.telemetry.state().mode == FlightMode.HOLD, 2.0, 0.01)
    delay = (rig.clock.now_ns() - lost) * 1e-9
    figure("failsafe_setpoint_loss", hold_after_s=delay)
    assert delay <= 1.0 and ap.telemetry.state().failsafe == "offboard_loss"


def test_failsafe_geofence_returns(fdm: PlantFactory) -> None:
    rig = FlightRig(fdm(), GF_MAX_HOR_DIST=30.0)
    rig.up(5.0)
    lat, lon = rig.geo(60.0, 0.0)
    assert rig.ap.action.reposition(lat * 1e-7, lon * 1e-7, None).ok
    rig.run_until(lambda: rig.ap.telemetry.state().mode == FlightMode.RTL, 40.0)
    figure("failsafe_geofence", breach_at_m=rig.pos[0])
    assert rig.ap.telemetry.state().failsafe == "geofence" and 29.0 < rig.pos[0] < 36.0
    rig.run_until(lambda: not rig.ap.telemetry.state().armed, 120.0)
    assert math.hypot(rig.pos[0], rig.pos[1]) < 1.5


def test_arming_refused_without_gps_fix(fdm_no_gps: PlantFactory) -> None:
    rig = FlightRig(fdm_no_gps())
    r = rig.ap.action.arm()
    figure("arming_without_gps", refused=float(r.result == Result.DENIED))
    assert r.result == Result.DENIED and "GPS" in r.reason
    assert not rig.ap.telemetry.state().armed
