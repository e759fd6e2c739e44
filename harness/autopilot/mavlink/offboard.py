"""Offboard setpoints: SET_POSITION_TARGET_LOCAL_NED, SET_POSITION_TARGET_GLOBAL_INT and SET_ATTITUDE_TARGET
to the autopilot API.

``type_mask`` bits say which fields to *ignore*; an ignored vector or yaw becomes ``None`` (unset). A vector
must be used or ignored as a whole (x, y and z together). Frames: LOCAL_NED (1)
and BODY_NED (8, MAVSDK's forward-right-down velocity); others are refused. The autopilot itself stamps
each setpoint with its sim time, denies OFFBOARD without a recent one and falls back (COM_OBL_RC_ACT)
when they stop for COM_OF_LOSS_T seconds of sim time, as PX4 in lockstep SITL does.
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import AttitudeTarget, CommandResult, OffboardFrame, OffboardSetpoint, VehicleState
from harness.autopilot.mavlink.messages import MAVLinkMessage
from harness.autopilot.services import System
from harness.core.geo import flat_offset_m

_POS = (
    mavlink2.POSITION_TARGET_TYPEMASK_X_IGNORE,
    mavlink2.POSITION_TARGET_TYPEMASK_Y_IGNORE,
    mavlink2.POSITION_TARGET_TYPEMASK_Z_IGNORE,
)
_VEL = (
    mavlink2.POSITION_TARGET_TYPEMASK_VX_IGNORE,
    mavlink2.POSITION_TARGET_TYPEMASK_VY_IGNORE,
    mavlink2.POSITION_TARGET_TYPEMASK_VZ_IGNORE,
)
_ACC = (
    mavlink2.POSITION_TARGET_TYPEMASK_AX_IGNORE,
    mavlink2.POSITION_TARGET_TYPEMASK_AY_IGNORE,
    mavlink2.POSITION_TARGET_TYPEMASK_AZ_IGNORE,
)
_YAW = mavlink2.POSITION_TARGET_TYPEMASK_YAW_IGNORE
_YAW_RATE = mavlink2.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
_FORCE = mavlink2.POSITION_TARGET_TYPEMASK_FORCE_SET

_ATT_RATES = (
    mavlink2.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE,
    mavlink2.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE,
    mavlink2.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE,
)
_ATT_THRUST_IGNORE = mavlink2.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE
_ATT_ATTITUDE_IGNORE = mavlink2.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE


class _Partial(Exception):
    pass


def _vector(
    mask: int, bits: tuple[int, int, int], values: tuple[float, float, float]
) -> tuple[float, float, float] | None:
    used = [not mask & b for b in bits]
    if not any(used):
        return None
    if not all(used):
        raise _Partial
    return values


def position_target(m: MAVLinkMessage) -> OffboardSetpoint | str:
    """The setpoint of a SET_POSITION_TARGET_LOCAL_NED, or why it is refused."""
    try:
        frame = OffboardFrame(m.coordinate_frame)
    except ValueError:
        return f"offboard setpoint frame {m.coordinate_frame} not supported (use LOCAL_NED 1 or BODY_NED 8)"
    mask = m.type_mask
    if mask & _FORCE:
        return "offboard force setpoints are not supported"
    try:
        pos = _vector(mask, _POS, (m.x, m.y, m.z))
        vel = _vector(mask, _VEL, (m.vx, m.vy, m.vz))
        acc = _vector(mask, _ACC, (m.afx, m.afy, m.afz))
    except _Partial:
        return "offboard setpoint ignores part of a vector: use or ignore x, y and z together"
    if pos is None and vel is None and acc is None:
        return "offboard setpoint ignores position, velocity and acceleration"
    sp = OffboardSetpoint(
        position_m=pos,
        velocity_m_s=vel,
        accel_m_s2=acc,
        yaw_rad=None if mask & _YAW else m.yaw,
        yaw_rate_rad_s=None if mask & _YAW_RATE else m.yaw_rate,
        frame=frame,
    )
    used = [v for vec in (pos, vel, acc) if vec is not None for v in vec]
    used += [v for v in (sp.yaw_rad, sp.yaw_rate_rad_s) if v is not None]
    if not all(math.isfinite(v) for v in used):
        return "offboard setpoint with NaN or infinite values"
    return sp


_GLOBAL_FRAMES = {0: False, 5: False, 3: True, 6: True}
"""SET_POSITION_TARGET_GLOBAL_INT frames -> altitude relative to home?"""


def global_target(m: MAVLinkMessage, state: VehicleState) -> OffboardSetpoint | str:
    """SET_POSITION_TARGET_GLOBAL_INT (MAVSDK ``set_position_global``) as a LOCAL_NED setpoint: the target
    is placed relative to the current estimate (flat earth around it: fine for offboard distances)."""
    rel = _GLOBAL_FRAMES.get(m.coordinate_frame)
    if rel is None:
        return f"global setpoint frame {m.coordinate_frame} not supported (use GLOBAL_INT or GLOBAL_RELATIVE_ALT_INT)"
    mask = m.type_mask
    if mask & _FORCE:
        return "offboard force setpoints are not supported"
    try:
        pos = _vector(mask, _POS, (m.lat_int * 1e-7, m.lon_int * 1e-7, m.alt))
        vel = _vector(mask, _VEL, (m.vx, m.vy, m.vz))
        acc = _vector(mask, _ACC, (m.afx, m.afy, m.afz))
    except _Partial:
        return "offboard setpoint ignores part of a vector: use or ignore x, y and z together"
    local: tuple[float, float, float] | None = None
    if pos is not None:
        lat, lon, alt = pos
        if not (math.isfinite(alt) and abs(lat) <= 90.0 and abs(lon) <= 180.0):
            return "global setpoint with invalid coordinates"
        if rel:
            if state.home is None:
                return "relative-altitude setpoint without a home position"
            alt += state.home.alt_amsl_m
        n0, e0, d0 = state.pos_ned_m
        dn, de = flat_offset_m(state.lat_deg, state.lon_deg, lat, lon)
        local = (n0 + dn, e0 + de, d0 - (alt - state.alt_amsl_m))
    if local is None and vel is None and acc is None:
        return "offboard setpoint ignores position, velocity and acceleration"
    sp = OffboardSetpoint(
        position_m=local,
        velocity_m_s=vel,
        accel_m_s2=acc,
        yaw_rad=None if mask & _YAW else m.yaw,
        yaw_rate_rad_s=None if mask & _YAW_RATE else m.yaw_rate,
        frame=OffboardFrame.LOCAL_NED,
    )
    used = [v for vec in (local, vel, acc) if vec is not None for v in vec]
    used += [v for v in (sp.yaw_rad, sp.yaw_rate_rad_s) if v is not None]
    if not all(math.isfinite(v) for v in used):
        return "offboard setpoint with NaN or infinite values"
    return sp


def attitude_target(m: MAVLinkMessage) -> AttitudeTarget | str:
    mask = m.type_mask
    quat = None if mask & _ATT_ATTITUDE_IGNORE else (m.q[0], m.q[1], m.q[2], m.q[3])
    rates_used = [not mask & b for b in _ATT_RATES]
    rates = None
    if any(rates_used):
        r = (m.body_roll_rate, m.body_pitch_rate, m.body_yaw_rate)
        rx, ry, rz = (v if u else 0.0 for v, u in zip(r, rates_used, strict=True))
        rates = (rx, ry, rz)
    if mask & _ATT_THRUST_IGNORE:
        return "attitude target without thrust is not supported"
    if quat is None and rates is None:
        return "attitude target ignores both attitude and body rates"
    return AttitudeTarget(quat=quat, thrust=m.thrust, body_rates_rad_s=rates)


def handle_setpoint(api: System, m: MAVLinkMessage) -> CommandResult:
    """Forward one setpoint message; a refusal carries the reason (counted and logged, never ACKed)."""
    mid = m.get_msgId()
    if mid in (
        mavlink2.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED,
        mavlink2.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT,
    ):
        sp = (
            position_target(m)
            if mid == mavlink2.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED
            else global_target(m, api.telemetry.state())
        )
        return CommandResult.denied(sp) if isinstance(sp, str) else api.offboard.set_setpoint(sp)
    att = attitude_target(m)
    return CommandResult.denied(att) if isinstance(att, str) else api.offboard.set_attitude(att)
