"""ArduPilot's SIM_* parameters on one vehicle (``harness.autopilot.simworld``): what each does to the sensor frame,
the motors, the battery and the physics' wind — and that nothing changes while they are at their defaults."""

from __future__ import annotations

import math

import pytest

from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.fdm.physics import Physics, PhysicsConfig


@pytest.fixture(scope="module")
def frame():  # type: ignore[no-untyped-def]
    phys = Physics(PhysicsConfig())
    for _ in range(300):  # 1.2 s: GPS, baro and mag have samples
        frames = phys.step([(0.0, 0.0, 0.0, 0.0)])
    f = frames[0]
    assert f.gps is not None and f.baro is not None and f.mag is not None
    return f


def test_defaults_change_nothing(frame) -> None:  # type: ignore[no-untyped-def]
    ap = Autopilot(AutopilotConfig())
    w = ap.world
    assert not w.active and not w.pending and w.sensors(frame) is frame
    assert ap.take_events() == [] and w.motors((0.5, 0.5, 0.5, 0.5)) == (0.5, 0.5, 0.5, 0.5)


def test_sensor_knobs(frame) -> None:  # type: ignore[no-untyped-def]
    ap = Autopilot(AutopilotConfig())
    p, w = ap.params, ap.world
    assert p.set("SIM_GPS_GLITCH_X", 0.001).ok and p.set("SIM_GPS_GLITCH_Z", 5.0).ok and w.active
    g = w.sensors(frame).gps
    assert g is not None and math.isclose(g.lat_deg, frame.gps.lat_deg + 0.001)
    assert math.isclose(g.alt_amsl_m, frame.gps.alt_amsl_m + 5.0) and g.lon_deg == frame.gps.lon_deg
    assert p.set("SIM_GPS_DISABLE", 1).ok and w.sensors(frame).gps is None
    assert p.set("SIM_BARO_GLITCH", 10.0).ok
    b = w.sensors(frame).baro
    assert b is not None and math.isclose(b.alt_amsl_m, frame.baro.alt_amsl_m + 10.0)
    assert math.isclose(b.pressure_pa, frame.baro.pressure_pa - 120.0)
    assert p.set("SIM_BARO_DISABLE", 1).ok and p.set("SIM_MAG1_FAIL", 1).ok
    out = w.sensors(frame)
    assert out.baro is None and out.mag is None and out.imu is frame.imu
    for name in ("SIM_GPS_GLITCH_X", "SIM_GPS_GLITCH_Z", "SIM_GPS_DISABLE", "SIM_BARO_GLITCH", "SIM_BARO_DISABLE"):
        p.set(name, 0)
    p.set("SIM_MAG1_FAIL", 0)
    assert not w.active and w.sensors(frame) is frame


def test_engine_failure_scales_the_masked_motors() -> None:
    ap = Autopilot(AutopilotConfig())
    assert ap.params.set("SIM_ENGINE_FAIL", 0b0101).ok and ap.params.set("SIM_ENGINE_MUL", 0.5).ok
    assert ap.world.motors((0.8, 0.8, 0.6, 0.6)) == (0.4, 0.8, 0.3, 0.6)


def test_battery_voltage_sets_the_charge() -> None:
    ap = Autopilot(AutopilotConfig())
    bat = ap.core.battery
    assert bat.open_circuit_v() == pytest.approx(16.8)
    assert ap.params.set("SIM_BATT_VOLTAGE", 15.4).ok
    assert bat.open_circuit_v() == pytest.approx(15.4, abs=1e-6) and 0 < bat.remaining < 1
    assert ap.params.set("SIM_BATT_VOLTAGE", 30.0).ok and bat.remaining == pytest.approx(1.0)  # clipped to full


def test_wind_and_pace_go_to_the_physics_once() -> None:
    ap = Autopilot(AutopilotConfig())
    assert ap.params.set("SIM_WIND_DIR", 270).ok and ap.params.set("SIM_WIND_SPD", 10).ok
    assert ap.params.set("SIM_WIND_TURB", 1.5).ok and ap.params.set("SIM_SPEEDUP", 5).ok
    (change,) = ap.take_events()
    n, e, d = change.wind_ned_m_s
    assert abs(n) < 1e-9 and math.isclose(e, 10.0) and d == 0.0  # from the west: the air moves east
    assert change.turbulence == 1.5 and change.speedup == 5.0
    assert ap.take_events() == []  # taken once
    phys = Physics(PhysicsConfig())
    phys.apply(0, change)
    assert phys.vehicles[0].turbulence.cfg.steady_ned_m_s == change.wind_ned_m_s
    assert phys.vehicles[0].turbulence.cfg.turbulence == 1.5
