"""The autopilot's ``gripper`` service: payload grippers opened and closed by MAV_CMD_DO_GRIPPER (PX4's
``payload_deliverer``, ArduPilot's ``AP_Gripper``), their state shown in telemetry (``VehicleState.grippers_grabbed``).

A gripper here is a latch: it acts at once (no servo travel time) and carries nothing the physics would feel.
"""

from __future__ import annotations

from harness.autopilot.api import CommandResult
from harness.autopilot.supervisor import Commander

INSTANCES = range(1, 7)
"""MAVLink's gripper instance numbers (DO_GRIPPER param 1)."""


class Grippers:
    """The grippers of one vehicle; every one open at start."""

    def __init__(self, ap: Commander) -> None:
        self.ap = ap
        self.grabbed: tuple[int, ...] = ()
        """The instances that hold a payload, in order."""

    def grab(self, instance: int = 1) -> CommandResult:
        return self._set(instance, True)

    def release(self, instance: int = 1) -> CommandResult:
        return self._set(instance, False)

    def _set(self, instance: int, closed: bool) -> CommandResult:
        if instance not in INSTANCES:
            return CommandResult.denied(f"no gripper {instance} (instances {INSTANCES[0]}..{INSTANCES[-1]})")
        ap = self.ap
        with ap.lock:
            held = set(self.grabbed)
            if closed:
                held.add(instance)
            else:
                held.discard(instance)
            self.grabbed = tuple(sorted(held))
            ap.state_changed()
            return CommandResult.accepted()
