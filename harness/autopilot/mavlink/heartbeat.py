"""HEARTBEAT: PX4 identity and custom modes, sent on the wall clock.

At least once per ``period_ns`` of wall time whatever the simulation does (MAVSDK disconnects after 3 s
without one, QGC after 3.5 s), and once more right after the armed state or the flight mode changes.
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
    """Decides when a heartbeat is due (wall clock)."""

    period_ns: int = 1_000_000_000
    _last_ns: int | None = None
    _last_key: tuple[bool, FlightMode] | None = None

    def due(self, now_ns: int, state: VehicleState) -> bool:
        key = (state.armed, state.mode)
        last = self._last_ns
        if last is None or key != self._last_key:
            self._last_ns = now_ns
        elif now_ns - last >= self.period_ns:  # keeps its phase (1 Hz on the dot, in step with the streams)
            nxt = last + self.period_ns
            self._last_ns = nxt if now_ns - nxt < self.period_ns else now_ns
        else:
            return False
        self._last_key = key
        return True

    def next_due_ns(self) -> int:
        """Wall time of the next periodic heartbeat (0: one is due now)."""
        return 0 if self._last_ns is None else self._last_ns + self.period_ns

    def force(self) -> None:
        """Send one at the next check (after a command that changes arming or mode)."""
        self._last_ns = None
