"""Telemetry streams: message builders from a ``VehicleState`` and a dual-clock stream scheduler.

A stream with interval T is sent when T has passed on the wall clock *or* on the sim clock since its
last send — the faster of its sim rate and its wall rate — so a GCS sees live telemetry while the
simulation is paused or slow, and dense telemetry when it runs faster than real time. ``time_boot_ms``
and ``time_usec`` are sim time and never go backwards. SET_MESSAGE_INTERVAL (command 511) changes
intervals of every message that has a builder here.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import FlightMode, VehicleState
from harness.autopilot.mavlink.messages import UINT16_MAX, MAVLinkMessage, clamp_int, finite

Builder = Callable[[mavlink2.MAVLink, VehicleState, int], MAVLinkMessage | None]
"""(encoder, state, time_boot_ms) -> message, or None when there is nothing to say (no home yet)."""

# MAV_SYS_STATUS_SENSOR bits MAVSDK's health reads.
SENSOR_GYRO = 0x1
SENSOR_ACCEL = 0x2
SENSOR_MAG = 0x4
SENSOR_BARO = 0x8
SENSOR_GPS = 0x20
SENSOR_GEOFENCE = 0x100000
"""Healthy unless the geofence failsafe is active (MAVProxy reports 'fence breach' otherwise)."""
SENSOR_PREARM = 0x10000000
SENSORS_PRESENT = SENSOR_GYRO | SENSOR_ACCEL | SENSOR_MAG | SENSOR_BARO | SENSOR_GPS | SENSOR_GEOFENCE | SENSOR_PREARM

_I32 = 2**31 - 1


def _deg_e7(deg: float) -> int:
    return clamp_int(deg * 1e7, -_I32, _I32)


def _heading_cdeg(yaw_rad: float) -> int:
    return clamp_int(math.degrees(finite(yaw_rad)) % 360.0 * 100.0, 0, 35999)


def health_bits(state: VehicleState) -> int:
    h = state.health
    bits = 0
    for ok, bit in (
        (h.gyro_ok, SENSOR_GYRO),
        (h.accel_ok, SENSOR_ACCEL),
        (h.mag_ok, SENSOR_MAG),
        (h.baro_ok, SENSOR_BARO),
        (h.gps_ok, SENSOR_GPS),
        (h.preflight_ok, SENSOR_PREARM),
        (state.failsafe != "geofence", SENSOR_GEOFENCE),
    ):
        if ok:
            bits |= bit
    return bits


def sys_status(mav: mavlink2.MAVLink, s: VehicleState, _t: int) -> MAVLinkMessage:
    b = s.battery
    return mav.sys_status_encode(
        SENSORS_PRESENT,
        SENSORS_PRESENT,
        health_bits(s),
        0,
        clamp_int(b.voltage_v * 1000.0, 0, UINT16_MAX - 1, UINT16_MAX),
        clamp_int(b.current_a * 100.0, -1, 32767, -1),
        clamp_int(b.remaining * 100.0, -1, 100, -1),
        0,
        0,
        0,
        0,
        0,
        0,
    )


def global_position_int(mav: mavlink2.MAVLink, s: VehicleState, t: int) -> MAVLinkMessage:
    vn, ve, vd = s.vel_ned_m_s
    return mav.global_position_int_encode(
        t,
        _deg_e7(s.lat_deg),
        _deg_e7(s.lon_deg),
        clamp_int(s.alt_amsl_m * 1000.0, -_I32, _I32),
        clamp_int(s.rel_alt_m * 1000.0, -_I32, _I32),
        clamp_int(vn * 100.0, -32768, 32767),
        clamp_int(ve * 100.0, -32768, 32767),
        clamp_int(vd * 100.0, -32768, 32767),
        _heading_cdeg(s.yaw_rad),
    )


def local_position_ned(mav: mavlink2.MAVLink, s: VehicleState, t: int) -> MAVLinkMessage:
    (x, y, z), (vx, vy, vz) = s.pos_ned_m, s.vel_ned_m_s
    return mav.local_position_ned_encode(t, x, y, z, vx, vy, vz)


def attitude(mav: mavlink2.MAVLink, s: VehicleState, t: int) -> MAVLinkMessage:
    p, q, r = s.rates_body_rad_s
    return mav.attitude_encode(t, s.roll_rad, s.pitch_rad, s.yaw_rad, p, q, r)


def attitude_quaternion(mav: mavlink2.MAVLink, s: VehicleState, t: int) -> MAVLinkMessage:
    w, x, y, z = s.quat
    p, q, r = s.rates_body_rad_s
    return mav.attitude_quaternion_encode(t, w, x, y, z, p, q, r, [0.0, 0.0, 0.0, 0.0])


def gps_raw_int(mav: mavlink2.MAVLink, s: VehicleState, _t: int) -> MAVLinkMessage:
    g = s.gps
    vn, ve, _vd = g.vel_ned_m_s
    speed = math.hypot(vn, ve)
    cog = clamp_int(math.degrees(math.atan2(ve, vn)) % 360.0 * 100.0, 0, 35999) if speed > 0.2 else UINT16_MAX
    return mav.gps_raw_int_encode(
        s.t_ns // 1000,
        clamp_int(g.fix_type, 0, 8),
        _deg_e7(g.lat_deg),
        _deg_e7(g.lon_deg),
        clamp_int(g.alt_amsl_m * 1000.0, -_I32, _I32),
        clamp_int(g.eph_m * 100.0, 0, UINT16_MAX, UINT16_MAX),
        clamp_int(g.epv_m * 100.0, 0, UINT16_MAX, UINT16_MAX),
        clamp_int(speed * 100.0, 0, UINT16_MAX - 1, UINT16_MAX),
        cog,
        clamp_int(g.satellites, 0, 255),
    )


def extended_sys_state(mav: mavlink2.MAVLink, s: VehicleState, _t: int) -> MAVLinkMessage:
    return mav.extended_sys_state_encode(mavlink2.MAV_VTOL_STATE_UNDEFINED, int(s.landed_state))


def battery_status(mav: mavlink2.MAVLink, s: VehicleState, _t: int) -> MAVLinkMessage:
    b = s.battery
    voltages = [UINT16_MAX] * 10
    voltages[0] = clamp_int(b.voltage_v * 1000.0, 0, UINT16_MAX - 1, UINT16_MAX)
    return mav.battery_status_encode(
        0,
        mavlink2.MAV_BATTERY_FUNCTION_ALL,
        mavlink2.MAV_BATTERY_TYPE_LIPO,
        32767,
        voltages,
        clamp_int(b.current_a * 100.0, -1, 32767, -1),
        clamp_int(b.consumed_mah, -1, _I32, -1),
        -1,
        clamp_int(b.remaining * 100.0, -1, 100, -1),
        0,
        mavlink2.MAV_BATTERY_CHARGE_STATE_OK,
        [0, 0, 0, 0],
        0,
        0,
    )


def vfr_hud(mav: mavlink2.MAVLink, s: VehicleState, _t: int) -> MAVLinkMessage:
    gs = finite(s.ground_speed_m_s)
    return mav.vfr_hud_encode(
        gs,
        gs,
        _heading_cdeg(s.yaw_rad) // 100,
        clamp_int(s.throttle * 100.0, 0, 100),
        finite(s.alt_amsl_m),
        -finite(s.vel_ned_m_s[2]),
    )


def home_position(mav: mavlink2.MAVLink, s: VehicleState, _t: int) -> MAVLinkMessage | None:
    home = s.home
    if home is None:
        return None
    x, y, z = s.home_ned_m or (0.0, 0.0, 0.0)
    return mav.home_position_encode(
        _deg_e7(home.lat_deg),
        _deg_e7(home.lon_deg),
        clamp_int(home.alt_amsl_m * 1000.0, -_I32, _I32),
        x,
        y,
        z,
        [1.0, 0.0, 0.0, 0.0],
        0.0,
        0.0,
        0.0,
        s.t_ns // 1000,
    )


def mission_state_of(s: VehicleState) -> int:
    m = s.mission
    if m.count == 0:
        return mavlink2.MISSION_STATE_NO_MISSION
    if m.finished:
        return mavlink2.MISSION_STATE_COMPLETE
    if m.active:
        return mavlink2.MISSION_STATE_ACTIVE
    if m.reached or m.current_seq > 0:
        return mavlink2.MISSION_STATE_PAUSED
    return mavlink2.MISSION_STATE_NOT_STARTED


def mission_current(mav: mavlink2.MAVLink, s: VehicleState, _t: int) -> MAVLinkMessage:
    m = s.mission
    in_mission = s.mode is FlightMode.MISSION
    return mav.mission_current_encode(
        clamp_int(m.current_seq, 0, UINT16_MAX - 1),
        clamp_int(m.count, 0, UINT16_MAX - 1),
        mission_state_of(s),
        1 if in_mission else 2,  # mission_mode: 1 in mission mode, 2 suspended (another mode)
    )


def highres_imu(mav: mavlink2.MAVLink, s: VehicleState, _t: int) -> MAVLinkMessage:
    """HIGHRES_IMU; ``fields_updated`` has a sensor's bits exactly when SYS_STATUS calls it healthy (accel 0-2,
    gyro 3-5, mag 6-8, absolute pressure 9, pressure altitude 11, temperature 12)."""
    ax, ay, az = s.accel_body_m_s2
    p, q, r = s.rates_body_rad_s
    h = s.health
    mx, my, mz = s.mag_body_gauss or (0.0, 0.0, 0.0)
    updated = (0x007 if h.accel_ok else 0) | (0x038 if h.gyro_ok else 0) | 0x1000
    if h.mag_ok and s.mag_body_gauss is not None:
        updated |= 0x1C0
    if h.baro_ok and s.baro_pa is not None:
        updated |= 0x200 | 0x800
    hpa = (s.baro_pa or 0.0) / 100.0
    return mav.highres_imu_encode(
        s.t_ns // 1000, ax, ay, az, p, q, r, mx, my, mz, hpa, 0.0, finite(s.alt_amsl_m), 25.0, updated, 0
    )


def altitude(mav: mavlink2.MAVLink, s: VehicleState, _t: int) -> MAVLinkMessage:
    """ALTITUDE (MAVSDK ``telemetry.altitude``): AMSL, local (up), above home; no terrain data."""
    amsl = finite(s.alt_amsl_m)
    return mav.altitude_encode(
        s.t_ns // 1000, amsl, amsl, -finite(s.pos_ned_m[2]), finite(s.rel_alt_m), math.nan, math.nan
    )


def system_time(mav: mavlink2.MAVLink, s: VehicleState, t: int) -> MAVLinkMessage:
    return mav.system_time_encode(0, t)


BUILDERS: dict[int, Builder] = {
    mavlink2.MAVLINK_MSG_ID_SYS_STATUS: sys_status,
    mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: global_position_int,
    mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: local_position_ned,
    mavlink2.MAVLINK_MSG_ID_ATTITUDE: attitude,
    mavlink2.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: attitude_quaternion,
    mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT: gps_raw_int,
    mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: extended_sys_state,
    mavlink2.MAVLINK_MSG_ID_BATTERY_STATUS: battery_status,
    mavlink2.MAVLINK_MSG_ID_VFR_HUD: vfr_hud,
    mavlink2.MAVLINK_MSG_ID_HOME_POSITION: home_position,
    mavlink2.MAVLINK_MSG_ID_MISSION_CURRENT: mission_current,
    mavlink2.MAVLINK_MSG_ID_HIGHRES_IMU: highres_imu,
    mavlink2.MAVLINK_MSG_ID_SYSTEM_TIME: system_time,
    mavlink2.MAVLINK_MSG_ID_ALTITUDE: altitude,
}
"""Every message a GCS can request (512) or stream (511), by message id."""

_HZ = 1_000_000_000
DEFAULT_INTERVALS_NS: dict[int, int] = {
    mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: _HZ // 10,
    mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: _HZ // 10,
    mavlink2.MAVLINK_MSG_ID_ATTITUDE: _HZ // 10,
    mavlink2.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: _HZ // 10,
    mavlink2.MAVLINK_MSG_ID_SYS_STATUS: _HZ // 2,
    mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT: _HZ // 2,
    mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: _HZ // 2,
    mavlink2.MAVLINK_MSG_ID_BATTERY_STATUS: _HZ // 2,
    mavlink2.MAVLINK_MSG_ID_VFR_HUD: _HZ // 4,
    mavlink2.MAVLINK_MSG_ID_MISSION_CURRENT: _HZ,
    mavlink2.MAVLINK_MSG_ID_ALTITUDE: _HZ // 2,
    mavlink2.MAVLINK_MSG_ID_HOME_POSITION: 2 * _HZ,  # PX4 streams it at 0.5 Hz: MAVSDK's home() stream needs it
}
"""Default stream intervals; messages not listed are sent only on request or event."""

MIN_INTERVAL_NS = 1_000_000
"""SET_MESSAGE_INTERVAL faster than 1 kHz is clamped."""


@dataclass(slots=True)
class _Stream:
    interval_ns: int
    last_wall_ns: int | None = None
    last_sim_ns: int | None = None


@dataclass(slots=True)
class StreamScheduler:
    """Which stream messages are due now: on sim time, as PX4's streams run on its (lockstep) clock; and on
    the wall clock while the sim stands still, so that a paused run still shows a ground station live
    telemetry. A sim that moves, however slowly (×0.4 with 100 vehicles), streams on sim time alone: a
    wall-clock fill-in would send each stream 2.5 times as often as PX4 would, all of it repeats."""

    defaults: dict[int, int] = field(default_factory=lambda: dict(DEFAULT_INTERVALS_NS))
    builders: Mapping[int, Builder] = field(default_factory=lambda: BUILDERS)
    """Messages that can be streamed (a personality adds its own to ``BUILDERS``)."""
    _streams: dict[int, _Stream] = field(default_factory=dict)
    _sim_ns: int = -1
    _sim_moved_wall_ns: int = 0
    """Wall time at which sim time was last seen to move."""

    def __post_init__(self) -> None:
        for msg_id, interval in self.defaults.items():
            self._streams[msg_id] = _Stream(interval)

    def set_interval(self, msg_id: int, interval_us: float) -> bool:
        """Command 511: -1 disables, 0 restores the default, > 0 sets the interval. False if unknown."""
        if msg_id not in self.builders or not math.isfinite(interval_us):
            return False
        if interval_us < 0:
            self._streams.pop(msg_id, None)
        elif interval_us == 0:
            default = self.defaults.get(msg_id)
            if default is None:
                self._streams.pop(msg_id, None)
            else:
                self._streams[msg_id] = _Stream(default)
        else:
            self._streams[msg_id] = _Stream(max(MIN_INTERVAL_NS, int(interval_us * 1000)))
        return True

    def interval_us(self, msg_id: int) -> int:
        """Current interval in µs for MESSAGE_INTERVAL (-1 = not streamed)."""
        s = self._streams.get(msg_id)
        return -1 if s is None else s.interval_ns // 1000

    def due(self, wall_ns: int, sim_ns: int) -> list[int]:
        """The streams due now (see :meth:`due_by_clock`)."""
        return [msg_id for msg_id, _ in self.due_by_clock(wall_ns, sim_ns)]

    def due_by_clock(self, wall_ns: int, sim_ns: int, keep_sim_grid: bool = True) -> list[tuple[int, bool]]:
        """The streams due now, each with whether only the wall clock made it due.

        On sim time a stream falls due once in each interval of a fixed grid, the multiples of its interval
        (``last_sim_ns`` is the start of the last slot served): the same seed gives the same messages at the
        same sim times, whenever and by whichever thread the server happens to be serviced, and streams whose
        intervals divide each other fall due together. On the wall clock a stream falls due only once sim time
        has stood still for one of its intervals (paused, or held by a mission); it keeps its phase on the clock
        that made it due (one interval after the previous one was due, not after it was served); one more than
        an interval behind starts again from now. A wall-clock send never moves the sim grid; without
        ``keep_sim_grid`` (no peer on sim time listens) it counts as the send of the current sim slot, so a slow
        sim does not send a stream twice as often as asked (once on each clock).
        """
        if sim_ns != self._sim_ns:
            self._sim_ns, self._sim_moved_wall_ns = sim_ns, wall_ns
        still_ns = wall_ns - self._sim_moved_wall_ns
        out = []
        for msg_id, s in self._streams.items():
            last_sim, last_wall, interval = s.last_sim_ns, s.last_wall_ns, s.interval_ns
            slot = sim_ns - sim_ns % interval
            by_wall = False
            if last_wall is None or last_sim is None or slot > last_sim:
                s.last_sim_ns, s.last_wall_ns = slot, wall_ns
            elif wall_ns - last_wall >= interval and still_ns >= interval:
                nxt = last_wall + interval
                s.last_wall_ns = nxt if wall_ns - nxt < interval else wall_ns
                by_wall = True
                if not keep_sim_grid:
                    s.last_sim_ns = slot
            else:
                continue
            out.append((msg_id, by_wall))
        return out

    def next_due_wall_ns(self) -> int | None:
        """Earliest wall time at which a stream falls due (for the server's select timeout)."""
        moved = self._sim_moved_wall_ns
        times = [
            max(s.last_wall_ns, moved) + s.interval_ns for s in self._streams.values() if s.last_wall_ns is not None
        ]
        return min(times) if times else None

    def next_due_sim_ns(self) -> int | None:
        """Earliest sim time at which a stream falls due (when the autopilot's bell must ring)."""
        times = [s.last_sim_ns + s.interval_ns for s in self._streams.values() if s.last_sim_ns is not None]
        return min(times) if times else None
