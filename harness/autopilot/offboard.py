"""The autopilot's ``offboard`` service: position / velocity / acceleration setpoints and attitude targets.

The last kind of input received is the one OFFBOARD flies; a setpoint is handed to the navigator at once while
OFFBOARD is active, else when the mode is entered (``apply``). The age of the last input is kept in sim time:
PX4 in lockstep SITL judges ``COM_OF_LOSS_T`` on its own (sim) clock, and a mission's setpoints and MAVSDK's
resends follow sim time (on the wall clock a loaded machine's gap between two phases read as a lost stream).
"""

from __future__ import annotations

import enum
import math

from harness.autopilot.api import AttitudeTarget, CommandResult, FlightMode, OffboardSetpoint
from harness.autopilot.supervisor import Commander
from harness.autopilot.validate import finite


class OffboardKind(enum.Enum):
    """Which offboard input came last: it is the one OFFBOARD mode flies."""

    NONE = enum.auto()
    SETPOINT = enum.auto()
    """Position / velocity / acceleration (SET_POSITION_TARGET_*)."""
    ATTITUDE = enum.auto()
    """Attitude and thrust (SET_ATTITUDE_TARGET)."""


class OffboardInput:
    """The offboard inputs of one vehicle."""

    def __init__(self, ap: Commander) -> None:
        self.ap = ap
        self.reset()

    def reset(self) -> None:
        """As at boot: no input received (a reboot of the flight stack)."""
        self.kind = OffboardKind.NONE
        self.setpoint: OffboardSetpoint | None = None
        self.attitude: AttitudeTarget | None = None
        self._t_ns = -(10**18)
        """Sim time of the last offboard input."""

    # ------------------------------------------------------------------ commands (any thread)
    def set_setpoint(self, sp: OffboardSetpoint) -> CommandResult:
        vals = [v for vec in (sp.position_m, sp.velocity_m_s, sp.accel_m_s2) if vec is not None for v in vec]
        vals += [v for v in (sp.yaw_rad, sp.yaw_rate_rad_s) if v is not None]
        if not finite(vals):
            return CommandResult.denied("offboard setpoint with NaN or infinite values")
        return self._set(sp)

    def _set(self, sp: OffboardSetpoint) -> CommandResult:
        ap = self.ap
        with ap.lock:
            self._t_ns = ap.core.t_ns
            self.setpoint, self.kind = sp, OffboardKind.SETPOINT
            if ap.core.mode == FlightMode.OFFBOARD:
                self.apply()
            return CommandResult.accepted()

    def set_axes(self, sp: OffboardSetpoint) -> CommandResult:
        """A setpoint whose NaN components leave their axis to the others, as ALTCTL's setpoints do
        (ArduCopter's attitude targets: a horizontal acceleration and a climb rate). Infinite values are refused."""
        vals = [v for vec in (sp.position_m, sp.velocity_m_s, sp.accel_m_s2) if vec is not None for v in vec]
        if any(math.isinf(v) for v in vals) or all(math.isnan(v) for v in vals):
            return CommandResult.denied("offboard setpoint with infinite values or no axis set")
        return self._set(sp)

    def set_attitude(self, target: AttitudeTarget) -> CommandResult:
        vals = [target.thrust, *(target.quat or ()), *(target.body_rates_rad_s or ())]
        if not finite(vals) or not 0.0 <= target.thrust <= 1.0:
            return CommandResult.denied("attitude target with NaN values or thrust outside [0, 1]")
        if target.quat is not None and abs(math.sqrt(sum(v * v for v in target.quat)) - 1.0) > 0.05:
            return CommandResult.denied("attitude target quaternion is not normalised")
        ap = self.ap
        with ap.lock:
            self._t_ns = ap.core.t_ns
            self.attitude, self.kind = target, OffboardKind.ATTITUDE
            if ap.core.mode == FlightMode.OFFBOARD:
                self.apply()
            return CommandResult.accepted()

    # ------------------------------------------------------------------ for the commander (under the lock)
    def apply(self) -> None:
        """Hand the last input to the navigator (entering OFFBOARD, or a new input while in it)."""
        nav = self.ap.core.nav
        if self.kind == OffboardKind.ATTITUDE:
            nav.fly_attitude(self.attitude)
        elif self.setpoint is not None:
            nav.set_offboard(self.setpoint)

    def age_s(self) -> float:
        """Sim seconds since the last offboard input."""
        return (self.ap.core.t_ns - self._t_ns) * 1e-9

    def climbing(self) -> bool:
        c = self.ap.core
        return c.mode == FlightMode.OFFBOARD and c.climb_requested(c.nav.sp)

    def flies_attitude(self) -> bool:
        return self.kind == OffboardKind.ATTITUDE
