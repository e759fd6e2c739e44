"""HEARTBEAT: PX4 identity and custom modes, on the faster of the sim and the wall clock.

At least once per ``period_ns`` of wall time whatever the simulation does (MAVSDK disconnects after 3 s
without one, QGC after 3.5 s), at least once per ``period_ns`` of sim time (scripts on the sim clock —
DroneKit's 5 s link timeout, a mode printer — see 1 Hz at any speed), and once more right after the armed
state or the flight mode changes.
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import FlightMode, VehicleState
from harness.autopilot.mavlink.codec import MAVLinkMessage

BASE_MODE_CUSTOM = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
BASE_MODE_ARMED = mavlink2.MAV_MODE_FLAG_SAFETY_ARMED


def heartbeat_fields(armed: bool, mode: FlightMode) -> tuple[int, int, int]:
    """(base_mode, custom_mode, system_status) as PX4 reports them."""
    base = BASE_MODE_CUSTOM | (BASE_MODE_ARMED if armed else 0)
    status = mavlink2.MAV_STATE_ACTIVE if armed else mavlink2.MAV_STATE_STANDBY
    return base, mode.custom_mode, status


def heartbeat_message(mav: mavlink2.MAVLink, state: VehicleState) -> MAVLinkMessage:
    base, custom, status = heartbeat_fields(state.armed, state.mode)
    return mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_PX4, base, custom, status, 3)


@dataclass(slots=True)
class HeartbeatSchedule:
    """Decides when a heartbeat is due: a period of wall time or of sim time (``state.t_ns``) passed."""

    period_ns: int = 1_000_000_000
    _last_ns: int | None = None
    _last_sim_ns: int | None = None
    _last_key: tuple[bool, FlightMode] | None = None
    by_wall: bool = False
    """Whether the last heartbeat found due was due only on the wall clock."""

    def due(self, now_ns: int, state: VehicleState, keep_sim_grid: bool = True) -> bool:
        """Whether a heartbeat is due; ``keep_sim_grid`` as for ``StreamScheduler.due_by_clock``."""
        key = (state.armed, state.mode)
        last, last_sim, sim = self._last_ns, self._last_sim_ns, state.t_ns
        period = self.period_ns
        slot = sim - sim % period
        if last_sim is None or slot > last_sim:
            # 1 Hz of sim time on a fixed grid (the multiples of the period; wall-clock sends never shift it):
            # the same seed gives the same heartbeats at the same sim times, whoever services the server when
            self._last_sim_ns = slot
            self.by_wall = False
        elif last is None or key != self._last_key:
            self.by_wall = False  # a change of arming or mode
        elif now_ns - last >= period:
            self.by_wall = True  # a second of wall time without one: the sim is slow or paused
            if not keep_sim_grid:
                self._last_sim_ns = slot
        else:
            return False
        self._last_ns = now_ns
        self._last_key = key
        return True

    def next_due_ns(self) -> int:
        """Wall time of the next periodic heartbeat (0: one is due now)."""
        return 0 if self._last_ns is None else self._last_ns + self.period_ns

    def next_due_sim_ns(self) -> int | None:
        """Sim time of the next periodic heartbeat (when the autopilot's bell must ring)."""
        return None if self._last_sim_ns is None else self._last_sim_ns + self.period_ns

    def force(self) -> None:
        """Send one at the next check (after a command that changes arming or mode)."""
        self._last_ns = None
