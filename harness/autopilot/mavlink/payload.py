"""The payload components PX4 SITL answers for beside the camera: the winch (``MAV_COMP_ID_WINCH``, 169), to which
MAVSDK's winch plugin addresses MAV_CMD_DO_WINCH (42600).

PX4's ``payload_deliverer`` takes DO_WINCH (as DO_GRIPPER) and accepts it; here the action (0 relax ... 9 load
payload, MAVLink's WINCH_ACTIONS) is checked and ACCEPTED from the winch component, which is what a script waits for
(``winch.py`` of MAVSDK-Python's examples). No winch is simulated: nothing hangs below the vehicle.
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import Result
from harness.autopilot.mavlink.commands import CommandIn
from harness.autopilot.mavlink.messages import MAVLinkMessage, Origin, Out

_M = mavlink2
COMPID = _M.MAV_COMP_ID_WINCH
_COMMANDS = (_M.MAVLINK_MSG_ID_COMMAND_LONG, _M.MAVLINK_MSG_ID_COMMAND_INT)
WINCH_ACTIONS = range(10)
"""MAVLink WINCH_ACTIONS: relaxed, relative length, rate, lock, deliver, hold, retract, load line, abandon line,
load payload."""


class WinchComponent:
    """Component 169 of the vehicle's system (no heartbeat of its own, as PX4's is internal)."""

    compid = COMPID

    def __init__(self) -> None:
        self.mav: mavlink2.MAVLink | None = None
        self.actions: list[int] = []
        """Every action accepted, in order."""

    def bind_component(self, mav: mavlink2.MAVLink) -> None:
        self.mav = mav

    def heartbeat(self) -> MAVLinkMessage | None:
        return None

    def handle_component(self, m: MAVLinkMessage, origin: Origin) -> list[Out]:
        if m.get_msgId() not in _COMMANDS:
            return []
        assert self.mav is not None
        c = CommandIn.from_message(m)
        if c.command != _M.MAV_CMD_DO_WINCH:
            result = Result.UNSUPPORTED
        else:
            action = c.params[1]
            ok = math.isfinite(action) and int(action) == action and int(action) in WINCH_ACTIONS
            result = Result.ACCEPTED if ok else Result.DENIED
            if ok:
                self.actions.append(int(action))
        ack = self.mav.command_ack_encode(c.command, int(result), 0, 0, origin.sysid, origin.compid)
        return [Out(ack, origin, compid=COMPID)]
