"""What the tick machine knows of a peer, the states it moves through, and the actions it asks for.

The machine (:mod:`harness.channel.machine`) is fed events (a message from a peer, a lost peer, an
expired wait) and answers with :data:`Action` values that the shell carries out: bytes to send, a
connection to close, in-process autopilots to step, a tick result for a local physics, the end of the run.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import NamedTuple

from harness.wire import protocol as p


class Phase(enum.IntEnum):
    """The paper's two phases of a tick."""

    ZERO = 0
    """Type-0 subscribers (missions) run inside the simulated world and ENQUEUE packets."""
    ONE = 1
    """Type-1 subscribers (network simulators) simulate the interval and DELIVER packets."""


class Role(enum.Enum):
    """Where the channel sits, decided by its upstream."""

    WAITING = "waiting"
    """No upstream yet (physics has not joined)."""
    ROOT = "root"
    """Its upstream is physics: it decides when the phases run."""
    CHILD = "child"
    """Its upstream is a parent channel: it obeys the parent's BEGIN-TICK-0/1 and answers for its subtree."""


class TickState(enum.Enum):
    """The autopilot half of a tick (BEGIN-TICK-AC out, END-TICK-AC back)."""

    IDLE = "idle"
    """Between ticks: joiners are admitted now."""
    COLLECTING = "collecting"
    """The tick began; its BEGIN-TICK-AC are still arriving from upstream."""
    AWAITING_HOLDERS = "awaiting holders"
    """Every BEGIN-TICK-AC is in, but a vehicle has no autopilot yet (the join deadline runs)."""
    STEPPING = "stepping"
    """BEGIN-TICK-AC routed to the holders; END-TICK-AC outstanding."""
    ANSWERED = "answered"
    """Every END-TICK-AC is in (a child has sent them up); the tick ends when its phases allow."""

    __hash__ = object.__hash__  # a table key looked up every tick: identity, not Enum's hash of the name


class PhaseState(enum.Enum):
    """The subscriber half of a tick. Phase 1 may outlive its tick (``overlap_phase1``): the peers still in
    it are the machine's ``wait1``, and no phase 0 starts before that set is empty."""

    NONE = "none"
    """This tick runs no phase (or, in a child, the parent has not started one)."""
    PENDING = "pending"
    """Root: this tick runs the phases; phase 0 waits for the previous phase 1 or the in-process autopilots."""
    ZERO = "phase 0"
    """BEGIN-TICK-0 sent; END-TICK-0 outstanding."""
    ZERO_DONE = "phase 0 done"
    """Every END-TICK-0 is in (a child has sent its own up)."""
    ONE = "phase 1"
    """BEGIN-TICK-1 sent for this tick."""

    __hash__ = object.__hash__


class PeerLink(enum.Enum):
    """How the machine reaches a peer."""

    SOCKET = "socket"
    """A connection the shell reads and writes."""
    IN_PROCESS = "in-process"
    """Autopilots in the channel's own process: a :class:`StepLocal` action steps them, no bytes at all."""


@dataclass(eq=False)
class PeerState:
    """One admitted (or about to be admitted) peer, as far as the tick is concerned."""

    pid: int
    name: str
    kind: p.PeerKind
    link: PeerLink = PeerLink.SOCKET
    vehicle: int = -1
    """The vehicle a type-0 subscriber belongs to (-1 for none)."""
    vehicles: set[int] = field(default_factory=set)
    """Vehicles an autopilot or child holds."""
    mission_vehicles: set[int] = field(default_factory=set)
    """A child's vehicles with missions below it (DELIVER routing)."""
    members: int = 0
    """A child channel's admitted subscribers (its own ANNOUNCE)."""
    exits_seen: int = 0
    """How many of a child's announced mission exits are in the machine's ``mission_exits``."""
    upstream: bool = False
    admitted: bool = False
    closed: bool = False
    waiting_for: str = ""
    idle_until_ns: int = p.EVERY_PHASE
    """Lookahead from its last END-TICK-0/1: leave it out of its phase before this sim time."""
    deliver_wakes: bool = True
    mavlink_wakes: bool = False
    """Its vehicle's MAVLink wakes it too (END-TICK-0 ``mavlink_wakes``): see ``TickMachine._needs_phase0``."""
    woken: bool = False
    """A WAKE (type 0) arrived: include it in the next phase 0."""
    delivered: bool = False
    """A DELIVER was routed to it (type 0) since its last phase 0."""

    @property
    def label(self) -> str:
        return f"{self.kind.name} {self.name!r}"

    @property
    def vehicle_note(self) -> str:
        if self.kind == p.PeerKind.TYPE0 and self.vehicle >= 0:
            return f" (vehicle {self.vehicle})"
        if self.vehicles:
            return f" (vehicles {sorted(self.vehicles)})"
        return ""


# --- actions (named tuples: one is made per message sent, so they must be cheap) -----------------------


class Send(NamedTuple):
    """Queue ``data`` (whole frames) for ``peer``."""

    peer: PeerState
    data: bytes


class StepLocal(NamedTuple):
    """Step the in-process autopilots of ``peer`` with these BEGIN-TICK-AC (after flushing what is queued,
    so remote peers work meanwhile) and feed their END-TICK-AC back (``TickMachine.local_answers``)."""

    peer: PeerState
    begin_ticks: tuple[p.BeginTickAC, ...]


class Close(NamedTuple):
    """Close ``peer``'s connection: ``error`` (a frame, may be empty) first, then what was queued."""

    peer: PeerState
    error: bytes = b""


class TickDone(NamedTuple):
    """The tick of a local physics is over: its END-TICK-AC, by vehicle."""

    end_ticks: tuple[p.EndTickAC, ...]


class Stop(NamedTuple):
    """The run is over (physics or the upstream left): send BYE ``reason`` to every peer below and stop."""

    reason: str


Action = Send | StepLocal | Close | TickDone | Stop


class Refused(Exception):
    """A HELLO the machine does not admit; the shell answers with ERROR ``code`` and closes."""

    def __init__(self, code: p.ErrorCode, why: str) -> None:
        super().__init__(why)
        self.code = code


class RunFailed(Exception):
    """The run cannot go on (a fatal fault, a lost parent, an upstream out of order)."""
