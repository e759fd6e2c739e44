"""GUIDED targets as ArduCopter takes them, turned into flight-core calls (pure functions over the state).

- SET_POSITION_TARGET_LOCAL_NED: frames LOCAL_NED (1), LOCAL_OFFSET_NED (7: position relative to the
  vehicle), BODY_NED (8) and BODY_OFFSET_NED (9: position and velocity in the heading frame, position
  relative to the vehicle). SET_POSITION_TARGET_GLOBAL_INT: GLOBAL(_INT) AMSL, GLOBAL_RELATIVE_ALT(_INT)
  and terrain frames (taken as relative to home: there is no terrain model).
- A position-only target is a *goto*: the vehicle flies there and holds it with no time limit (the core's
  reposition); a target with a velocity runs on the core's offboard control, which ArduCopter stops after
  GUID_TIMEOUT without a new one (DroneKit's examples resend velocities every second).
- MISSION_ITEM / MISSION_ITEM_INT with current = 2 is a goto (DroneKit's ``simple_goto``), current = 3
  changes only the altitude.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import MavFrame, OffboardFrame, OffboardSetpoint, VehicleState
from harness.autopilot.mavlink.messages import MAVLinkMessage
from harness.core.geo import flat_offset_m, flat_point

_POS_IGNORE = 0b111
_VEL_IGNORE = 0b111 << 3
_ACC_IGNORE = 0b111 << 6
_YAW_IGNORE = mavlink2.POSITION_TARGET_TYPEMASK_YAW_IGNORE
_YAW_RATE_IGNORE = mavlink2.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE

RELATIVE_GLOBAL = {
    MavFrame.GLOBAL: False,
    MavFrame.GLOBAL_INT: False,
    MavFrame.GLOBAL_RELATIVE_ALT: True,
    MavFrame.GLOBAL_RELATIVE_ALT_INT: True,
    MavFrame.GLOBAL_TERRAIN_ALT: True,
    MavFrame.GLOBAL_TERRAIN_ALT_INT: True,
}
"""Global frames -> is the altitude relative to home?"""


@dataclass(frozen=True, slots=True)
class Goto:
    """Fly to this point and hold it."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    yaw_rad: float | None = None


@dataclass(frozen=True, slots=True)
class Velocity:
    """A velocity (and optionally position) target on the core's offboard control."""

    setpoint: OffboardSetpoint


def geo_of_local(state: VehicleState, ned: tuple[float, float, float]) -> tuple[float, float, float]:
    """A point of the core's local frame as (lat, lon, alt AMSL), flat earth around the vehicle."""
    n0, e0, d0 = state.pos_ned_m
    lat, lon = flat_point(state.lat_deg, state.lon_deg, ned[0] - n0, ned[1] - e0)
    return lat, lon, state.alt_amsl_m - (ned[2] - d0)


def _rotate(yaw: float, v: tuple[float, float, float]) -> tuple[float, float, float]:
    c, s = math.cos(yaw), math.sin(yaw)
    return (c * v[0] - s * v[1], s * v[0] + c * v[1], v[2])


def _yaw_of(mask: int, yaw: float, yaw_rate: float) -> tuple[float | None, float | None]:
    return (None if mask & _YAW_IGNORE else yaw), (None if mask & _YAW_RATE_IGNORE else yaw_rate)


def local_target(m: MAVLinkMessage, state: VehicleState) -> Goto | Velocity | str:
    """SET_POSITION_TARGET_LOCAL_NED as a goto or a velocity target, or why it is refused."""
    frame, mask = m.coordinate_frame, m.type_mask
    if frame not in (MavFrame.LOCAL_NED, MavFrame.LOCAL_OFFSET_NED, MavFrame.BODY_NED, MavFrame.BODY_OFFSET_NED):
        return f"position target frame {frame} not supported (LOCAL_NED, LOCAL_OFFSET_NED, BODY_NED, BODY_OFFSET_NED)"
    use_pos, use_vel = not mask & _POS_IGNORE, not mask & _VEL_IGNORE
    if not use_pos and not use_vel:
        return "position target ignores both position and velocity (acceleration-only targets are not supported)"
    values = [m.x, m.y, m.z, m.vx, m.vy, m.vz, m.yaw, m.yaw_rate]
    if not all(math.isfinite(v) for v in values):
        return "position target with NaN or infinite values"
    body = frame in (MavFrame.BODY_NED, MavFrame.BODY_OFFSET_NED)
    relative = frame != MavFrame.LOCAL_NED
    yaw, yaw_rate = _yaw_of(mask, m.yaw, m.yaw_rate)
    pos: tuple[float, float, float] | None = None
    if use_pos:
        p = _rotate(state.yaw_rad, (m.x, m.y, m.z)) if body else (m.x, m.y, m.z)
        if relative:
            n0, e0, d0 = state.pos_ned_m
            p = (n0 + p[0], e0 + p[1], d0 + p[2])
        pos = p
    if not use_vel:
        assert pos is not None
        lat, lon, alt = geo_of_local(state, pos)
        return Goto(lat, lon, alt, yaw)
    sp = OffboardSetpoint(
        position_m=pos,
        velocity_m_s=(m.vx, m.vy, m.vz),
        yaw_rad=yaw,
        yaw_rate_rad_s=yaw_rate,
        frame=OffboardFrame.BODY_NED if body and pos is None else OffboardFrame.LOCAL_NED,
    )
    if body and pos is not None:  # position given: the velocity goes in the local frame too
        sp = OffboardSetpoint(pos, _rotate(state.yaw_rad, (m.vx, m.vy, m.vz)), None, yaw, yaw_rate)
    return Velocity(sp)


def global_target(m: MAVLinkMessage, state: VehicleState) -> Goto | Velocity | str:
    """SET_POSITION_TARGET_GLOBAL_INT as a goto or a velocity target, or why it is refused."""
    relative = RELATIVE_GLOBAL.get(m.coordinate_frame)
    if relative is None:
        return f"global position target frame {m.coordinate_frame} not supported"
    mask = m.type_mask
    use_pos, use_vel = not mask & _POS_IGNORE, not mask & _VEL_IGNORE
    if not use_pos and not use_vel:
        return "position target ignores both position and velocity (acceleration-only targets are not supported)"
    yaw, yaw_rate = _yaw_of(mask, m.yaw, m.yaw_rate)
    point: tuple[float, float, float] | None = None
    if use_pos:
        p = global_point(m.lat_int * 1e-7, m.lon_int * 1e-7, m.alt, relative, state)
        if isinstance(p, str):
            return p
        point = p
    if not use_vel:
        assert point is not None
        return Goto(point[0], point[1], point[2], yaw)
    if not all(math.isfinite(v) for v in (m.vx, m.vy, m.vz)):
        return "position target with NaN or infinite velocity"
    local = None
    if point is not None:
        n0, e0, d0 = state.pos_ned_m
        dn, de = flat_offset_m(state.lat_deg, state.lon_deg, point[0], point[1])
        local = (n0 + dn, e0 + de, d0 - (point[2] - state.alt_amsl_m))
    return Velocity(OffboardSetpoint(local, (m.vx, m.vy, m.vz), None, yaw, yaw_rate))


def global_point(
    lat: float, lon: float, alt: float, relative: bool, state: VehicleState
) -> tuple[float, float, float] | str:
    if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt)) or abs(lat) > 90 or abs(lon) > 180:
        return f"invalid target coordinates ({lat}, {lon}, {alt})"
    if relative:
        if state.home is None:
            return "target altitude relative to home given but there is no home position yet"
        alt += state.home.alt_amsl_m
    return (lat, lon, alt)


def mission_item_goto(m: MAVLinkMessage, state: VehicleState) -> Goto | str:
    """MISSION_ITEM(_INT) with current = 2 (guided goto) or 3 (altitude change only)."""
    relative = RELATIVE_GLOBAL.get(m.frame)
    if relative is None:
        return f"guided waypoint frame {m.frame} not supported (use a global frame)"
    is_int = m.get_msgId() == mavlink2.MAVLINK_MSG_ID_MISSION_ITEM_INT
    lat, lon = (m.x * 1e-7, m.y * 1e-7) if is_int else (float(m.x), float(m.y))
    if m.current == 3:
        lat, lon = state.lat_deg, state.lon_deg
    p = global_point(lat, lon, float(m.z), relative, state)
    if isinstance(p, str):
        return p
    return Goto(p[0], p[1], p[2])


_ATT_YAW_RATE_IGNORE = mavlink2.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE
_ATT_THRUST_IGNORE = mavlink2.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE
_ATT_ATTITUDE_IGNORE = mavlink2.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE
_G = 9.80665
MAX_TILT_RAD = math.radians(60.0)


def climb_rate_of_thrust(thrust: float, up_m_s: float, down_m_s: float) -> float:
    """ArduCopter's reading of SET_ATTITUDE_TARGET's thrust with GUID_OPTIONS bit 3 clear (the default): a
    climb rate, 0.5 = hold the altitude, 1 = climb at WPNAV_SPEED_UP, 0 = descend at WPNAV_SPEED_DN (m/s, up +)."""
    t = min(max(thrust, 0.0), 1.0)
    if t > 0.5:
        return (t - 0.5) * 2.0 * up_m_s
    return -(0.5 - t) * 2.0 * abs(down_m_s)


def attitude_target(m: MAVLinkMessage, st: VehicleState, up_m_s: float, down_m_s: float) -> OffboardSetpoint | str:
    """A SET_ATTITUDE_TARGET in GUIDED / GUIDED_NOGPS as a core setpoint: the roll and pitch asked for as the
    horizontal acceleration they make (g tan(angle), the heading frame), the thrust as a climb rate, the
    yaw from the quaternion (or the body yaw rate when its bit is clear). Or why it is refused."""
    mask = m.type_mask
    if mask & _ATT_THRUST_IGNORE:
        return "SET_ATTITUDE_TARGET without thrust is ignored in GUIDED (ArduCopter needs it)"
    q = tuple(float(v) for v in m.q)
    if mask & _ATT_ATTITUDE_IGNORE or not all(math.isfinite(v) for v in q) or sum(v * v for v in q) < 1e-6:
        roll = pitch = 0.0
        yaw: float | None = None
    else:
        n = math.sqrt(sum(v * v for v in q))
        w, x, y, z = (v / n for v in q)
        roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
        pitch = math.asin(min(max(2.0 * (w * y - z * x), -1.0), 1.0))
        yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    yaw_rate: float | None = None
    if not mask & _ATT_YAW_RATE_IGNORE and math.isfinite(m.body_yaw_rate):
        yaw_rate, yaw = float(m.body_yaw_rate), None
    if not math.isfinite(m.thrust):
        return "SET_ATTITUDE_TARGET: thrust is not finite"
    roll = min(max(roll, -MAX_TILT_RAD), MAX_TILT_RAD)
    pitch = min(max(pitch, -MAX_TILT_RAD), MAX_TILT_RAD)
    fwd, right = -_G * math.tan(pitch), _G * math.tan(roll)
    heading = st.yaw_rad
    c, s = math.cos(heading), math.sin(heading)
    accel = (fwd * c - right * s, fwd * s + right * c, math.nan)
    vz = -climb_rate_of_thrust(float(m.thrust), up_m_s, down_m_s)
    return OffboardSetpoint(None, (math.nan, math.nan, vz), accel, yaw, yaw_rate if yaw is None else None)
