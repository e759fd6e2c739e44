"""The autopilot's ``mission`` service: the mission the navigator flies, the geofence and the rally points."""

from __future__ import annotations

from collections.abc import Sequence

from harness.autopilot.api import CommandResult, FlightMode, MissionItem, MissionKind
from harness.autopilot.services import Action
from harness.autopilot.supervisor import Commander
from harness.autopilot.validate import check_mission


class MissionPlans:
    """Mission, fence and rally items of one vehicle; start and pause go through ``action``'s mode change."""

    def __init__(self, ap: Commander, action: Action) -> None:
        self.ap = ap
        self.action = action
        self.rally: tuple[MissionItem, ...] = ()

    def upload(self, items: Sequence[MissionItem], kind: MissionKind = MissionKind.MISSION) -> CommandResult:
        why = check_mission(items, kind)
        if why:
            return CommandResult.denied(why) if not why.startswith("unsupported") else CommandResult.unsupported(why)
        ap = self.ap
        with ap.lock:
            if kind == MissionKind.MISSION:
                ap.core.nav.load_mission(items)
            elif kind == MissionKind.FENCE:
                ap.core.fence.set_items(items)
            else:
                self.rally = tuple(items)
            ap.state_changed()
            return CommandResult.accepted()

    def download(self, kind: MissionKind = MissionKind.MISSION) -> tuple[MissionItem, ...]:
        core = self.ap.core
        with self.ap.lock:
            if kind == MissionKind.MISSION:
                return tuple(core.nav.items)
            return core.fence.items if kind == MissionKind.FENCE else self.rally

    def clear(self, kind: MissionKind = MissionKind.MISSION) -> CommandResult:
        return self.upload((), kind)

    def set_current(self, seq: int) -> CommandResult:
        ap = self.ap
        with ap.lock:
            nav = ap.core.nav
            if not 0 <= seq < len(nav.items):
                return CommandResult.denied(f"mission item {seq} does not exist ({len(nav.items)} items)")
            nav.set_current(seq)
            ap.state_changed()
            return CommandResult.accepted()

    def start(self) -> CommandResult:
        return self.action.set_mode(FlightMode.MISSION)

    def pause(self) -> CommandResult:
        return self.action.set_mode(FlightMode.HOLD)
