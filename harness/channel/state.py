"""The tick's state as an object of its own, and every transition it may make in one table (h11's
``ConnectionState`` and ``EVENT_TRIGGERED_TRANSITIONS``, next to :class:`~harness.channel.machine.TickMachine`).

A tick has two halves that move separately: :class:`~harness.channel.events.TickState` follows the autopilots
(BEGIN-TICK-AC out, END-TICK-AC back), :class:`~harness.channel.events.PhaseState` the subscribers (phase 0,
phase 1). The machine names what happened (:class:`TickEvent`, :class:`PhaseEvent`); :class:`TickProgress`
looks the new state up in :data:`TICK_TRANSITIONS` / :data:`PHASE_TRANSITIONS` and refuses anything the
tables do not list — a bug in the machine, reported as a failed run instead of a silently wrong tick.
"""

from __future__ import annotations

import enum

from harness.channel.events import PhaseState, RunFailed, TickState


class TickEvent(enum.Enum):
    BEGIN = "the first BEGIN-TICK-AC (or a child's BEGIN-TICK-0) of a tick"
    HOLDER_MISSING = "every BEGIN-TICK-AC is in but a vehicle has no autopilot yet"
    ROUTED = "BEGIN-TICK-AC sent to every vehicle's autopilot"
    ANSWERED = "every END-TICK-AC is in"
    END = "the tick is over (phases included)"

    __hash__ = object.__hash__  # looked up every tick: identity, not Enum's Python-level hash of the name


class PhaseEvent(enum.Enum):
    TICK_WITH_PHASES = "a root's tick that runs the phases began"
    TICK_WITHOUT_PHASES = "a tick without phases began (a child waits for its parent's)"
    BEGIN0 = "BEGIN-TICK-0 sent"
    END0 = "every END-TICK-0 is in"
    BEGIN1 = "BEGIN-TICK-1 sent"

    __hash__ = object.__hash__


_T, _P = TickState, PhaseState

TICK_TRANSITIONS: dict[TickState, dict[TickEvent, TickState]] = {
    _T.IDLE: {TickEvent.BEGIN: _T.COLLECTING},
    _T.COLLECTING: {
        TickEvent.HOLDER_MISSING: _T.AWAITING_HOLDERS,
        TickEvent.ROUTED: _T.STEPPING,
        TickEvent.END: _T.IDLE,  # a child's tick opened by its parent's BEGIN-TICK-0 after its autopilots answered
    },
    _T.AWAITING_HOLDERS: {TickEvent.ROUTED: _T.STEPPING},
    _T.STEPPING: {TickEvent.ANSWERED: _T.ANSWERED},
    _T.ANSWERED: {TickEvent.END: _T.IDLE},
}
"""The autopilot half: IDLE → COLLECTING → [AWAITING_HOLDERS] → STEPPING → ANSWERED → IDLE. A child whose
autopilots answered before its parent's BEGIN-TICK-0 came has ended that tick: the BEGIN-TICK-0 opens it again
(COLLECTING, no BEGIN-TICK-AC to wait for) for its phases only, and phase 1's end closes it from there."""

_NEW_TICK = {PhaseEvent.TICK_WITH_PHASES: _P.PENDING, PhaseEvent.TICK_WITHOUT_PHASES: _P.NONE}
PHASE_TRANSITIONS: dict[PhaseState, dict[PhaseEvent, PhaseState]] = {
    _P.NONE: {**_NEW_TICK, PhaseEvent.BEGIN0: _P.ZERO},
    _P.PENDING: {PhaseEvent.BEGIN0: _P.ZERO},
    _P.ZERO: {PhaseEvent.END0: _P.ZERO_DONE},
    _P.ZERO_DONE: {PhaseEvent.BEGIN1: _P.ONE},
    _P.ONE: dict(_NEW_TICK),
}
"""The subscriber half: NONE, or PENDING → ZERO → ZERO_DONE → ONE; a child goes NONE → ZERO when its parent's
BEGIN-TICK-0 comes. A tick begins from NONE or ONE (phase 1 may still run beside the next tick: the peers in it
are the machine's ``wait1``)."""


class TickProgress:
    """Where the channel's current tick stands: both halves, changed only through the tables."""

    __slots__ = ("phase", "tick")

    def __init__(self) -> None:
        self.tick = TickState.IDLE
        self.phase = PhaseState.NONE

    def on(self, event: TickEvent) -> TickState:
        new = TICK_TRANSITIONS[self.tick].get(event)
        if new is None:
            raise RunFailed(f"tick machine: {event.value} while the tick is {self.tick.value}")
        self.tick = new
        return new

    def on_phase(self, event: PhaseEvent) -> PhaseState:
        new = PHASE_TRANSITIONS[self.phase].get(event)
        if new is None:
            raise RunFailed(f"tick machine: {event.value} while the phases are {self.phase.value}")
        self.phase = new
        return new
