"""What a pilot or a ground station's tracker sends without a reply: MANUAL_CONTROL (sticks,
``harness.autopilot.manual``) and FOLLOW_TARGET (the target's position, ``harness.autopilot.follow``).

Both go to optional services of the autopilot (``system.manual_control``, ``system.follow_me``); an autopilot
without them (None) refuses the messages as unsupported (counted as refused by the server).
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import CommandResult
from harness.autopilot.mavlink.messages import MAVLinkMessage
from harness.autopilot.services import System

PILOT_IDS = frozenset({mavlink2.MAVLINK_MSG_ID_MANUAL_CONTROL, mavlink2.MAVLINK_MSG_ID_FOLLOW_TARGET})
_EST_VEL = 1 << 1
"""FOLLOW_TARGET ``est_capabilities`` bit: the velocity fields are valid."""


def handle_pilot(api: System, m: MAVLinkMessage, sysid: int) -> CommandResult:
    """Hand one MANUAL_CONTROL or FOLLOW_TARGET to the autopilot."""
    if m.get_msgId() == mavlink2.MAVLINK_MSG_ID_MANUAL_CONTROL:
        if m.target not in (0, sysid):
            return CommandResult.accepted()  # another vehicle's sticks
        sticks = api.manual_control
        if sticks is None:
            return CommandResult.unsupported("manual control is not implemented by this autopilot")
        return sticks.set_sticks(int(m.x), int(m.y), int(m.z), int(m.r))
    follow = api.follow_me
    if follow is None:
        return CommandResult.unsupported("follow target is not implemented by this autopilot")
    vel = (
        (float(m.vel[0]), float(m.vel[1]), float(m.vel[2]))
        if m.est_capabilities & _EST_VEL
        else (math.nan, math.nan, math.nan)
    )
    return follow.set_target(m.lat * 1e-7, m.lon * 1e-7, float(m.alt), vel)
