"""Who is in the channel: peers by id, admission between ticks, and the per-membership caches of routing.

The base of :class:`~harness.channel.machine.TickMachine` (no I/O either): it answers "who holds vehicle
v", "which missions fly on v", "which peers of these kinds take part" and tells the parent channel what
this subtree holds (ANNOUNCE).
"""

from __future__ import annotations

from collections.abc import Iterable

from harness.channel.config import MissionExit
from harness.channel.events import Action, PeerLink, PeerState, Role, Send
from harness.wire import protocol as p


class Membership:
    def __init__(self, name: str) -> None:
        self.name = name
        self.peers: dict[int, PeerState] = {}
        self.up: PeerState | None = None
        self.role = Role.WAITING
        """Decided by the upstream: physics makes this channel the root, a parent channel a child."""
        self.actions: list[Action] = []
        self.unadmitted = 0
        self.in_process_peers = 0
        """In-process autopilot peers: phase 0 waits for their step in every tick."""
        self.mission_exits: list[MissionExit] = []
        """Every mission that ended below this channel (its own and, through ANNOUNCE, its children's)."""
        """Peers that joined during a tick; admitted when it ends."""
        self._members: dict[p.PeerKind, list[PeerState]] | None = None
        self._routes: dict[int, list[PeerState]] | None = None
        self._holders: dict[int, PeerState] | None = None

    def set_upstream(self, up: PeerState | None) -> None:
        self.up = up
        if up is None:
            self.role = Role.WAITING
        else:
            self.role = Role.ROOT if up.kind == p.PeerKind.PHYSICS else Role.CHILD

    # -- output -------------------------------------------------------------------------------------------

    def send(self, peer: PeerState, msg: p.Message) -> None:
        self.send_raw(peer, p.encode(msg))

    def send_raw(self, peer: PeerState, data: bytes) -> None:
        if not peer.closed:
            self.actions.append(Send(peer, data))

    # -- admission ------------------------------------------------------------------------------------------

    def _admit(self, peer: PeerState) -> None:
        peer.admitted = True
        self.membership_changed()
        self._announce_up()

    def _admit_pending(self) -> None:
        if not self.unadmitted:
            return
        self.unadmitted = 0
        self.in_process_peers = 0
        """In-process autopilot peers: phase 0 waits for their step in every tick."""
        for peer in list(self.peers.values()):
            if not peer.admitted and not peer.closed:
                self._admit(peer)

    def membership_changed(self) -> None:
        self._members = self._routes = self._holders = None

    def _announce_up(self) -> None:
        up = self.up
        if up is None or up.kind != p.PeerKind.CHILD:
            return
        held: set[int] = set()
        missions: set[int] = set()
        for peer in self.active():
            if peer.kind in (p.PeerKind.AUTOPILOT, p.PeerKind.CHILD):
                held |= peer.vehicles
            if peer.kind == p.PeerKind.TYPE0 and peer.vehicle >= 0:
                missions.add(peer.vehicle)
            if peer.kind == p.PeerKind.CHILD:
                missions |= peer.mission_vehicles
        exits = tuple((e.peer, e.vehicle, e.exit_code, e.reason) for e in self.mission_exits)
        self.send(up, p.Announce(tuple(sorted(held)), tuple(sorted(missions)), self.tree_size(), exits))

    # -- queries (cached per membership) ----------------------------------------------------------------------

    def active(self, *kinds: p.PeerKind) -> Iterable[PeerState]:
        """Admitted peers below this channel, of ``kinds`` (all kinds if none)."""
        members = self._members
        if members is None:
            members = {}
            for peer in self.peers.values():
                if peer.admitted and not peer.upstream and not peer.closed:
                    members.setdefault(peer.kind, []).append(peer)
            self._members = members
        if not kinds:
            return [peer for group in members.values() for peer in group]
        if len(kinds) == 1:
            return members.get(kinds[0], ())
        return [peer for kind in kinds for peer in members.get(kind, ())]

    def holders(self) -> dict[int, PeerState]:
        """The autopilot (or child) that answers for each vehicle; in-process autopilots come first."""
        holders = self._holders
        if holders is None:
            holders = {}
            peers = list(self.active(p.PeerKind.AUTOPILOT, p.PeerKind.CHILD))
            peers.sort(key=lambda peer: peer.link is PeerLink.IN_PROCESS)
            for peer in peers:
                for v in peer.vehicles:
                    holders[v] = peer
            self._holders = holders
        return holders

    def routes(self) -> dict[int, list[PeerState]]:
        """The type-0 subscribers of each vehicle (where a DELIVER for it goes)."""
        routes = self._routes
        if routes is None:
            routes = {}
            for peer in self.active(p.PeerKind.TYPE0):
                routes.setdefault(peer.vehicle, []).append(peer)
            self._routes = routes
        return routes

    def held_vehicles(self) -> set[int]:
        """Vehicles some autopilot or child below this channel holds (admitted or about to be)."""
        held: set[int] = set()
        for peer in self.peers.values():
            if peer.kind in (p.PeerKind.AUTOPILOT, p.PeerKind.CHILD) and not peer.upstream and not peer.closed:
                held |= peer.vehicles
        return held

    def missions_below(self) -> int:
        """Missions of vehicles still running in the child channels below this one (as they announced)."""
        return sum(len(peer.mission_vehicles) for peer in self.active(p.PeerKind.CHILD))

    def subscribers(self) -> list[tuple[str, str]]:
        """(name, kind) of every admitted peer below this channel that connected to it."""
        return [
            (peer.name, peer.kind.name)
            for peer in list(self.peers.values())
            if peer.admitted and not peer.upstream and peer.link is PeerLink.SOCKET
        ]

    def tree_size(self) -> int:
        """Admitted subscribers in the whole tree below this channel: its own, and what each child announced."""
        return sum(
            1 + (peer.members if peer.kind == p.PeerKind.CHILD else 0)
            for peer in list(self.peers.values())
            if peer.admitted and not peer.upstream and not peer.closed and peer.link is PeerLink.SOCKET
        )
