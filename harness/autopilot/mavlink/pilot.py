"""What a pilot or a ground station's tracker sends without a reply: MANUAL_CONTROL (sticks,
``harness.autopilot.manual``) and FOLLOW_TARGET (the target's position, ``harness.autopilot.follow``).

Both go to optional hooks of the autopilot (``manual_control``, ``follow_target``); an autopilot without
them ignores the messages (counted as refused by the server).
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import AutopilotApi, CommandResult
from harness.autopilot.mavlink.messages import MAVLinkMessage

PILOT_IDS = frozenset({mavlink2.MAVLINK_MSG_ID_MANUAL_CONTROL, mavlink2.MAVLINK_MSG_ID_FOLLOW_TARGET})
_EST_VEL = 1 << 1
"""FOLLOW_TARGET ``est_capabilities`` bit: the velocity fields are valid."""


def handle_pilot(api: AutopilotApi, m: MAVLinkMessage, sysid: int) -> CommandResult:
    """Hand one MANUAL_CONTROL or FOLLOW_TARGET to the autopilot."""
    if m.get_msgId() == mavlink2.MAVLINK_MSG_ID_MANUAL_CONTROL:
        if m.target not in (0, sysid):
            return CommandResult.accepted()  # another vehicle's sticks
        sticks = getattr(api, "manual_control", None)
        if sticks is None:
            return CommandResult.unsupported("manual control is not implemented by this autopilot")
        return sticks(int(m.x), int(m.y), int(m.z), int(m.r))
    follow = getattr(api, "follow_target", None)
    if follow is None:
        return CommandResult.unsupported("follow target is not implemented by this autopilot")
    vel = tuple(float(v) for v in m.vel) if m.est_capabilities & _EST_VEL else (math.nan, math.nan, math.nan)
    return follow(m.lat * 1e-7, m.lon * 1e-7, float(m.alt), vel)
