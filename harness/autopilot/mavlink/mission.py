"""The mission protocol (integer form) for missions, fences and rally points.

Upload:   GCS MISSION_COUNT -> we MISSION_REQUEST_INT(0) -> MISSION_ITEM_INT(0) -> ... -> MISSION_ACK.
Download: GCS MISSION_REQUEST_LIST -> we MISSION_COUNT -> MISSION_REQUEST_INT(seq) -> MISSION_ITEM_INT ...
Also MISSION_CLEAR_ALL, MISSION_SET_CURRENT, and the progress messages (MISSION_CURRENT on change,
MISSION_ITEM_REACHED for every item). Upload timeouts and retries run on the wall clock: a request that
gets no item within ``retry_ns`` is sent again, up to ``max_retries`` times, then the transfer is cancelled.
A legacy float MISSION_ITEM is converted and accepted the same way.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import SKIPPED_MISSION_COMMANDS, CommandResult, MissionItem, MissionKind, Result
from harness.autopilot.mavlink.messages import MAVLinkMessage, Origin, Out, clamp_int
from harness.autopilot.mavlink.mission_items import ItemResult, px4_item_result
from harness.autopilot.services import System

log = logging.getLogger(__name__)

MAX_ITEMS = 2000
MISSION_TYPE_ALL = 255
_LOCAL_SCALE = 1e4
"""MISSION_ITEM_INT x/y for local frames: metres * 1e4."""

_RESULT_TO_MISSION = {
    Result.DENIED: mavlink2.MAV_MISSION_DENIED,
    Result.UNSUPPORTED: mavlink2.MAV_MISSION_UNSUPPORTED,
    Result.TEMPORARILY_REJECTED: mavlink2.MAV_MISSION_DENIED,
    Result.FAILED: mavlink2.MAV_MISSION_ERROR,
}


def item_from_message(m: MAVLinkMessage, kind: MissionKind) -> MissionItem:
    """MISSION_ITEM_INT (or float MISSION_ITEM) to a ``MissionItem`` (global x/y as degrees*1e7 ints).

    Items that have no position (speed, gimbal and camera items) get NaN coordinates from MAVSDK; they
    mean nothing there, so they become 0 (the flight core refuses non-finite coordinates on any item).
    """
    probe = MissionItem(0, m.frame, m.command)
    is_int = m.get_msgId() == mavlink2.MAVLINK_MSG_ID_MISSION_ITEM_INT
    x: int | float
    y: int | float
    if m.command in SKIPPED_MISSION_COMMANDS:
        x, y = 0, 0
    elif probe.is_global:
        x, y = (
            (m.x, m.y)
            if is_int
            else (clamp_int(m.x * 1e7, -(2**31), 2**31 - 1), clamp_int(m.y * 1e7, -(2**31), 2**31 - 1))
        )
    else:
        x, y = (m.x / _LOCAL_SCALE, m.y / _LOCAL_SCALE) if is_int else (float(m.x), float(m.y))
    return MissionItem(
        seq=m.seq,
        frame=m.frame,
        command=m.command,
        param1=m.param1,
        param2=m.param2,
        param3=m.param3,
        param4=m.param4,
        x=x,
        y=y,
        z=0.0 if m.command in SKIPPED_MISSION_COMMANDS and not math.isfinite(m.z) else m.z,
        autocontinue=bool(m.autocontinue),
        current=bool(m.current),
        mission_type=kind,
    )


def item_to_message(
    mav: mavlink2.MAVLink, it: MissionItem, seq: int, target: Origin, kind: int, current: bool
) -> MAVLinkMessage:
    if it.is_global:
        x = it.x if isinstance(it.x, int) else clamp_int(it.x * 1e7, -(2**31), 2**31 - 1)
        y = it.y if isinstance(it.y, int) else clamp_int(it.y * 1e7, -(2**31), 2**31 - 1)
    else:
        x = clamp_int(float(it.x) * _LOCAL_SCALE, -(2**31), 2**31 - 1)
        y = clamp_int(float(it.y) * _LOCAL_SCALE, -(2**31), 2**31 - 1)
    return _encode(mav.mission_item_int_encode, it, seq, target, kind, current, x, y)


def item_to_float_message(
    mav: mavlink2.MAVLink, it: MissionItem, seq: int, target: Origin, kind: int, current: bool
) -> MAVLinkMessage:
    """The float MISSION_ITEM (degrees, metres) that DroneKit and older ground stations read."""
    x = it.lat_deg if it.is_global else float(it.x)
    y = it.lon_deg if it.is_global else float(it.y)
    return _encode(mav.mission_item_encode, it, seq, target, kind, current, x, y)


@dataclass(slots=True)
class _Upload:
    origin: Origin
    kind: int
    count: int
    items: list[MissionItem] = field(default_factory=list)
    last_ns: int = 0
    retries: int = 0


class MissionService:
    """Mission transfers for one autopilot. Server thread only."""

    def __init__(
        self,
        api: System,
        mav: mavlink2.MAVLink,
        retry_ns: int = 1_500_000_000,
        max_retries: int = 5,
        float_form: bool = False,
        check_item: Callable[[MAVLinkMessage], ItemResult] = px4_item_result,
    ) -> None:
        self.api = api
        self.check_item = check_item
        """The firmware's own check of each item as it arrives (``mission_items.py``): a refused item ends the
        upload with the firmware's MAV_MISSION_RESULT."""
        self.float_form = float_form
        """ArduPilot: ask for items with MISSION_REQUEST (DroneKit answers nothing else) and answer a
        MISSION_REQUEST with a float MISSION_ITEM; the _INT forms keep working."""
        self.mav = mav
        self.retry_ns = retry_ns
        self.max_retries = max_retries
        self._upload: _Upload | None = None
        self._last_done: tuple[int, tuple[str, int], int, int, int] | None = None
        """(link, address, kind, count, ack code) of the last finished upload, to answer a repeated last item."""
        self._downloads: dict[tuple[int, tuple[str, int], int], tuple[MissionItem, ...]] = {}
        self.refusals: list[CommandResult] = []
        """Reasons of refused transfers since the last call of ``pop_refusals`` (sent as STATUSTEXT)."""

    def pop_refusals(self) -> list[CommandResult]:
        out, self.refusals = self.refusals, []
        return out

    def _ack(self, to: Origin, code: int, kind: int) -> Out:
        return Out(self.mav.mission_ack_encode(to.sysid, to.compid, code, kind), to)

    def _request(self, up: _Upload, now_ns: int) -> Out:
        up.last_ns = now_ns
        seq = len(up.items)
        encode = self.mav.mission_request_encode if self.float_form else self.mav.mission_request_int_encode
        return Out(encode(up.origin.sysid, up.origin.compid, seq, up.kind), up.origin)

    def handle(self, m: MAVLinkMessage, origin: Origin, now_ns: int) -> list[Out]:
        mid = m.get_msgId()
        if mid == mavlink2.MAVLINK_MSG_ID_MISSION_COUNT:
            return self._count(m, origin, now_ns)
        if mid in (mavlink2.MAVLINK_MSG_ID_MISSION_ITEM_INT, mavlink2.MAVLINK_MSG_ID_MISSION_ITEM):
            return self._item(m, origin, now_ns)
        if mid == mavlink2.MAVLINK_MSG_ID_MISSION_REQUEST_LIST:
            return self._request_list(m, origin)
        if mid in (mavlink2.MAVLINK_MSG_ID_MISSION_REQUEST_INT, mavlink2.MAVLINK_MSG_ID_MISSION_REQUEST):
            return self._send_item(m, origin)
        if mid == mavlink2.MAVLINK_MSG_ID_MISSION_ACK:
            self._downloads.pop((origin.link, origin.addr, m.mission_type), None)
            return []
        if mid == mavlink2.MAVLINK_MSG_ID_MISSION_CLEAR_ALL:
            return self._clear(m, origin)
        if mid == mavlink2.MAVLINK_MSG_ID_MISSION_SET_CURRENT:
            r = self.api.mission.set_current(m.seq)
            if not r.ok:
                self.refusals.append(r)
            return []
        return []

    def _count(self, m: MAVLinkMessage, origin: Origin, now_ns: int) -> list[Out]:
        kind = m.mission_type
        if kind not in (0, 1, 2):
            return [self._ack(origin, mavlink2.MAV_MISSION_UNSUPPORTED, kind)]
        if m.count > MAX_ITEMS:
            self.refusals.append(CommandResult.denied(f"mission of {m.count} items refused (at most {MAX_ITEMS})"))
            return [self._ack(origin, mavlink2.MAV_MISSION_NO_SPACE, kind)]
        if m.count == 0:
            return [self._finish(origin, kind, [])]
        self._upload = _Upload(origin, kind, m.count)
        return [self._request(self._upload, now_ns)]

    def _item(self, m: MAVLinkMessage, origin: Origin, now_ns: int) -> list[Out]:
        up = self._upload
        if up is None:
            last = self._last_done
            if last is not None and last[:3] == (origin.link, origin.addr, m.mission_type) and m.seq == last[3] - 1:
                return [self._ack(origin, last[4], m.mission_type)]  # our ACK was lost: the last item again
            return [self._ack(origin, mavlink2.MAV_MISSION_OPERATION_CANCELLED, m.mission_type)]
        if up.origin.addr != origin.addr or up.origin.link != origin.link or m.mission_type != up.kind:
            return []
        expected = len(up.items)
        if m.seq != expected:
            return [self._request(up, now_ns)]  # duplicate or out of order: ask again for the one we need
        code, reason = self.check_item(m)
        if code != mavlink2.MAV_MISSION_ACCEPTED:
            self._upload = None
            self.refusals.append(CommandResult.denied(f"mission refused: {reason}"))
            return [self._ack(origin, code, up.kind)]
        try:
            up.items.append(item_from_message(m, MissionKind(up.kind)))
        except (ValueError, OverflowError) as e:
            self._upload = None
            self.refusals.append(CommandResult.denied(f"mission item {m.seq} invalid: {e}"))
            return [self._ack(origin, mavlink2.MAV_MISSION_ERROR, up.kind)]
        up.retries = 0
        if len(up.items) < up.count:
            return [self._request(up, now_ns)]
        self._upload = None
        ack = self._finish(origin, up.kind, up.items)
        self._last_done = (origin.link, origin.addr, up.kind, up.count, ack.msg.type)
        return [ack]

    def _finish(self, origin: Origin, kind: int, items: list[MissionItem]) -> Out:
        result = (
            self.api.mission.upload(items, MissionKind(kind)) if items else self.api.mission.clear(MissionKind(kind))
        )
        if result.ok:
            return self._ack(origin, mavlink2.MAV_MISSION_ACCEPTED, kind)
        self.refusals.append(result)
        return self._ack(origin, _RESULT_TO_MISSION.get(result.result, mavlink2.MAV_MISSION_ERROR), kind)

    def _request_list(self, m: MAVLinkMessage, origin: Origin) -> list[Out]:
        kind = m.mission_type
        if kind not in (0, 1, 2):
            return [self._ack(origin, mavlink2.MAV_MISSION_UNSUPPORTED, kind)]
        items = self.api.mission.download(MissionKind(kind))
        self._downloads[(origin.link, origin.addr, kind)] = items
        return [Out(self.mav.mission_count_encode(origin.sysid, origin.compid, len(items), kind), origin)]

    def _send_item(self, m: MAVLinkMessage, origin: Origin) -> list[Out]:
        kind = m.mission_type
        if kind not in (0, 1, 2):
            return [self._ack(origin, mavlink2.MAV_MISSION_UNSUPPORTED, kind)]
        items = self._downloads.get((origin.link, origin.addr, kind))
        if items is None:
            items = self.api.mission.download(MissionKind(kind))
        if not 0 <= m.seq < len(items):
            return [self._ack(origin, mavlink2.MAV_MISSION_INVALID_SEQUENCE, kind)]
        current = kind == 0 and m.seq == self.api.telemetry.state().mission.current_seq
        if self.float_form and m.get_msgId() == mavlink2.MAVLINK_MSG_ID_MISSION_REQUEST:
            return [Out(item_to_float_message(self.mav, items[m.seq], m.seq, origin, kind, current), origin)]
        return [Out(item_to_message(self.mav, items[m.seq], m.seq, origin, kind, current), origin)]

    def _clear(self, m: MAVLinkMessage, origin: Origin) -> list[Out]:
        kinds = (0, 1, 2) if m.mission_type == MISSION_TYPE_ALL else (m.mission_type,)
        if any(k not in (0, 1, 2) for k in kinds):
            return [self._ack(origin, mavlink2.MAV_MISSION_UNSUPPORTED, m.mission_type)]
        for k in kinds:
            r = self.api.mission.clear(MissionKind(k))
            if not r.ok:
                self.refusals.append(r)
                return [self._ack(origin, _RESULT_TO_MISSION.get(r.result, mavlink2.MAV_MISSION_ERROR), m.mission_type)]
        return [self._ack(origin, mavlink2.MAV_MISSION_ACCEPTED, m.mission_type)]

    def tick(self, now_ns: int) -> list[Out]:
        """Re-request a missing item after ``retry_ns`` of wall time; give up after ``max_retries``."""
        up = self._upload
        if up is None or now_ns - up.last_ns < self.retry_ns:
            return []
        if up.retries >= self.max_retries:
            self._upload = None
            log.info("mission upload from %s:%d timed out at item %d", *up.origin.addr, len(up.items))
            self.refusals.append(CommandResult.failed(f"mission upload timed out waiting for item {len(up.items)}"))
            return [self._ack(up.origin, mavlink2.MAV_MISSION_OPERATION_CANCELLED, up.kind)]
        up.retries += 1
        return [self._request(up, now_ns)]

    def next_retry_ns(self) -> int | None:
        """Wall time at which :meth:`tick` has a retry (or a timeout) to send; None when no upload runs."""
        up = self._upload
        return None if up is None else up.last_ns + self.retry_ns

    @property
    def uploading(self) -> bool:
        return self._upload is not None


class ProgressTracker:
    """Tells when MISSION_CURRENT must go out at once (current item, count or mission state changed)."""

    def __init__(self) -> None:
        self._last: tuple[int, int, int, bool] | None = None

    def changed(self, current_seq: int, count: int, mission_state: int, in_mission: bool) -> bool:
        key = (current_seq, count, mission_state, in_mission)
        if key != self._last:
            self._last = key
            return True
        return False


def _encode(
    encode: Callable[..., MAVLinkMessage],
    it: MissionItem,
    seq: int,
    target: Origin,
    kind: int,
    current: bool,
    x: float,
    y: float,
) -> MAVLinkMessage:
    """MISSION_ITEM and MISSION_ITEM_INT have the same fields; only x/y differ in type and scale."""
    return encode(
        target.sysid,
        target.compid,
        seq,
        it.frame,
        it.command,
        1 if current else 0,
        1 if it.autocontinue else 0,
        it.param1,
        it.param2,
        it.param3,
        it.param4,
        x,
        y,
        it.z,
        kind,
    )
