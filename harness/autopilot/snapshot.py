"""Building the frozen ``VehicleState`` snapshot from the live flight core and the commander's state (called
under the autopilot's lock)."""

from __future__ import annotations

from harness.autopilot.api import (
    Failsafe,
    FlightMode,
    GeoPoint,
    GpsInfo,
    Health,
    LandedState,
    MissionProgress,
    VehicleState,
)
from harness.autopilot.failures import FailureInjector, FailureUnit
from harness.autopilot.flight import FlightCore
from harness.autopilot.mathutil import quat_to_euler
from harness.core.geo import Vec3

GPS_TIMEOUT_NS = 4_000_000_000
"""A GPS that sent nothing for this long is gone (ArduPilot's AP_GPS ``GPS_TIMEOUT_MS``)."""


def build_state(
    c: FlightCore,
    vehicle: int,
    home: GeoPoint | None,
    home_ned: Vec3 | None,
    failsafe: Failsafe,
    preflight_ok: bool,
    failures: FailureInjector,
    grippers_grabbed: tuple[int, ...] = (),
) -> VehicleState:
    e = c.est
    nav = c.nav
    t = max(c.t_ns, 0)
    lat, lon, alt = e.geo()
    roll, pitch, yaw = quat_to_euler(e.q)
    g = e.gps
    gps = (  # a receiver silent for GPS_TIMEOUT_NS reports no GPS (a disabled or failed one: fix type 0)
        GpsInfo(g.fix_type, g.satellites, g.eph_m, g.epv_m, g.lat_deg, g.lon_deg, g.alt_amsl_m, g.vel_ned_m_s)
        if g is not None and t - g.measured_at_ns < GPS_TIMEOUT_NS
        else GpsInfo()
    )
    fresh = 1_000_000_000
    imu_ok = c.t_ns >= 0 and t - e.last_imu_ns < fresh
    failed = failures.off
    health = Health(
        gyro_ok=imu_ok and not failed(FailureUnit.SENSOR_GYRO),
        accel_ok=imu_ok and not failed(FailureUnit.SENSOR_ACCEL),
        mag_ok=t - e.last_mag_ns < 2 * fresh,
        baro_ok=t - e.last_baro_ns < fresh,
        gps_ok=e.global_position_ok(c.t_ns),
        gps_fix_ok=e.gps_fix_ok() and e.pos_valid,
        local_position_ok=e.pos_valid,
        home_ok=home is not None,
        preflight_ok=preflight_ok,
    )
    home_pd = home_ned[2] if home_ned is not None else 0.0
    mode = c.mode
    return VehicleState(
        t_ns=t,
        vehicle=vehicle,
        armed=c.armed,
        mode=mode,
        landed_state=c.landed_state if c.armed else LandedState.ON_GROUND,
        pos_ned_m=(e.pn, e.pe, e.pd),
        vel_ned_m_s=(e.vn, e.ve, e.vd),
        lat_deg=lat,
        lon_deg=lon,
        alt_amsl_m=alt,
        rel_alt_m=home_pd - e.pd,
        quat=e.q,
        roll_rad=roll,
        pitch_rad=pitch,
        yaw_rad=yaw,
        rates_body_rad_s=e.rates,
        accel_body_m_s2=e.accel_body,
        mag_body_gauss=failures.last_mag_gauss,
        baro_pa=failures.last_baro_pa,
        home=home,
        home_ned_m=home_ned,
        battery=c.battery.state(),
        gps=gps,
        health=health,
        mission=MissionProgress(
            current_seq=min(nav.current, max(len(nav.items) - 1, 0)),
            count=len(nav.items),
            reached=tuple(nav.reached),
            finished=nav.finished,
            active=mode == FlightMode.MISSION and c.armed,
        ),
        offboard_active=mode == FlightMode.OFFBOARD,
        motors=c.motors,
        throttle=c.collective,
        max_speed_m_s=nav.cruise_m_s,
        failsafe=failsafe,
        fence_max_hor_m=c.fence.max_hor_m,
        grippers_grabbed=grippers_grabbed,
    )
