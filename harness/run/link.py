"""The native vehicle link: physics and our own autopilots exchange each tick through the root channel.

:class:`NativeLink` is the first :class:`~harness.fdm.link.VehicleLink`: BEGIN-TICK-AC / END-TICK-AC of the
paper through the root channel (which also runs the missions' and network's phases). It joins the physics
layer to the channel, so it lives with the launcher that builds both.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Protocol

from harness.autopilot.api import TickStatus
from harness.autopilot.events import VehicleEvent, encode_events
from harness.channel import Channel
from harness.core.geo import Vec3
from harness.fdm.frame import SensorFrame, encode_frame
from harness.wire import protocol as p


class LocalFlightStack(Protocol):
    """A flight stack stepped inside the physics process (``harness.autopilot.Autopilot``)."""

    def step(self, frame: SensorFrame) -> tuple[float, float, float, float]: ...
    def tick_status(self) -> TickStatus: ...
    def take_events(self) -> list[VehicleEvent]: ...


class NativeLink:
    """Our autopilots through the root channel (which also runs the missions' and network's phases).

    Autopilots in this process (``local``) are stepped by the channel in the tick's phase 0 with the
    frame object itself; only autopilots in other processes get it encoded in their BEGIN-TICK-AC.
    """

    def __init__(
        self,
        channel: Channel,
        local: Mapping[int, LocalFlightStack] | None = None,
        mavlink_sent: Mapping[int, Callable[[], bool]] | None = None,
    ) -> None:
        """``mavlink_sent``: by local vehicle, whether its server sent MAVLink to missions on sim time since the last
        call (``MavlinkServer.sent_to_missions``): the END-TICK-AC of each tick with phases says so (``mavlink``), as
        a host's do."""
        self.channel = channel
        self._phase_every = channel.config.phase_every
        self._local = dict(local or {})
        self._frames: dict[int, SensorFrame] = {}
        self._sent = dict(mavlink_sent or {})
        if self._local:
            channel.attach_local_autopilots(self._local, self._step_local)

    def _step_local(self, m: p.BeginTickAC) -> p.EndTickAC:
        v = m.vehicle
        stack = self._local[v]
        motors = stack.step(self._frames[v])
        status = p.pack_status(*stack.tick_status())
        taken = stack.take_events()
        events = encode_events(taken) if taken else b""
        sent = self._sent.get(v)
        if sent is None or m.tick % self._phase_every:
            return p.EndTickAC(m.t_ns, v, motors, status, events=events)
        # after the step: what its bell sent in this tick counts
        return p.EndTickAC(m.t_ns, v, motors, status, b"", 1 if sent() else 0, events)

    def exchange(
        self, t_ns: int, tick: int, frames: Sequence[SensorFrame], elsewhere: Mapping[int, Vec3] | None = None
    ) -> list[p.EndTickAC]:
        """One tick: the BEGIN-TICK-AC of the vehicles simulated here (``frames``) and of those whose
        physics runs with their autopilot in a worker (``elsewhere``, at the ticks with phases: vehicle ->
        its last known position; no frame, and the worker's END-TICK-AC brings its ticks since the last);
        the answers by vehicle. A tick with neither is no tick for the channel."""
        remote = elsewhere or {}
        n = len(frames) + len(remote)
        local = self._local
        msgs = []
        for f in frames:
            if f.vehicle in local:
                self._frames[f.vehicle] = f
                msgs.append(p.BeginTickAC(t_ns, tick, f.vehicle, n, f.truth.pos_ned_m, b""))
            else:
                msgs.append(p.BeginTickAC(t_ns, tick, f.vehicle, n, f.truth.pos_ned_m, encode_frame(f)))
        for v, pos in remote.items():
            msgs.append(p.BeginTickAC(t_ns, tick, v, n, pos, b""))
        return self.channel.step(msgs) if msgs else []

    def close(self) -> None:
        self.channel.close("end of run")
