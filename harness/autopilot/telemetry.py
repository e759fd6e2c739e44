"""The autopilot's ``telemetry`` service (the state snapshot, status texts, mission items reached) and its
``bell`` (how the stepping thread tells the MAVLink side that something is due)."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

from harness.autopilot.api import MissionReached, ModeStatus, StatusText, VehicleState
from harness.autopilot.failures import FailureInjector
from harness.autopilot.gripper import Grippers
from harness.autopilot.snapshot import build_state
from harness.autopilot.supervisor import Commander, arming_check


class TelemetryFeed:
    """What one vehicle reports. The snapshot is built on demand and kept until the next step or command."""

    def __init__(self, ap: Commander, failures: FailureInjector, gripper: Grippers) -> None:
        self.ap = ap
        self.failures = failures
        self.gripper = gripper
        self.texts: deque[StatusText] = deque(maxlen=200)
        self.reached: deque[MissionReached] = deque(maxlen=1000)
        self.cache: VehicleState | None = None

    def state(self) -> VehicleState:
        ap = self.ap
        with ap.lock:
            if self.cache is None:
                preflight_ok = arming_check(ap) == ""
                self.cache = build_state(
                    ap.core,
                    ap.vehicle,
                    ap.home,
                    ap.home_ned,
                    ap.failsafe,
                    preflight_ok,
                    self.failures,
                    self.gripper.grabbed,
                )
            return self.cache

    def pop_status_texts(self) -> list[StatusText]:
        with self.ap.lock:
            out = list(self.texts)
            self.texts.clear()
            return out

    def pop_mission_reached(self) -> list[MissionReached]:
        with self.ap.lock:
            out = list(self.reached)
            self.reached.clear()
            return out

    def arming_check(self) -> str:
        """'' when the vehicle may arm, else the first reason it may not."""
        return arming_check(self.ap)


class TelemetryBell:
    """Lets the stepping thread call ``ring()`` (after the step, outside the lock) when the MAVLink side has
    something to do: the MAVLink server then sends its sim-rate telemetry in lockstep, at the tick it falls
    due, whatever the speed of the simulation.

    It rings once sim time reaches the time given to :meth:`ring_at` (the next sim-rate telemetry stream),
    or as soon as the flight mode, arming or landed state changes, a status text is said or a mission item
    is reached; then it stays silent until :meth:`ring_at` arms it again.
    """

    __slots__ = ("_at_ns", "_ring", "_rung_status", "armed")

    def __init__(self) -> None:
        self._ring: Callable[[], None] | None = None
        self.armed = False
        self._at_ns = 0
        self._rung_status: ModeStatus | None = None

    def attach(self, ring: Callable[[], None]) -> None:
        self._ring = ring
        self.ring_at(0)

    def ring_at(self, t_ns: int) -> None:
        """Arm the bell for sim time ``t_ns`` (any thread; the MAVLink server calls it after each service)."""
        if self._ring is not None:
            self._at_ns = t_ns
            self.armed = True

    def due(self, t_ns: int, status: ModeStatus, news: bool) -> Callable[[], None] | None:
        """After a step (under the lock, only while :attr:`armed`): the call to make outside the lock, if it rings."""
        if t_ns >= self._at_ns or news or status != self._rung_status:
            self.armed = False
            self._rung_status = status
            return self._ring
        return None
