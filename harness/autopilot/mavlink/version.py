"""AUTOPILOT_VERSION: capabilities and version numbers, as MAVSDK and QGC read them.

Without MISSION_INT in ``capabilities`` every MAVSDK mission upload fails; PARAM_ENCODE_BYTEWISE tells
ground stations how INT32 parameters travel. ``flight_sw_version`` uses PX4's layout
(major << 24 | minor << 16 | patch << 8 | type, type 255 = release).
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.mavlink.messages import MAVLinkMessage

CAPABILITIES = (
    mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink2.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
    | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
    | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
)

FLIGHT_SW_VERSION = (1 << 24) | (15 << 16) | (0 << 8) | 255
"""Reported as PX4 1.15.0 release: the PX4 behaviour docs/mavlink.md describes."""

_CUSTOM_VERSION = [0] * 8
"""PX4 puts its git hash here; we have none to give."""


def autopilot_version(mav: mavlink2.MAVLink, sysid: int) -> MAVLinkMessage:
    return mav.autopilot_version_encode(
        CAPABILITIES,
        FLIGHT_SW_VERSION,
        0,
        0,
        0,
        _CUSTOM_VERSION,
        [0] * 8,
        [0] * 8,
        0,
        0,
        0x4841524E45535300 | sysid,  # "HARNESS" + sysid: unique per vehicle
        [0] * 18,
    )
