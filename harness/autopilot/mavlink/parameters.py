"""The parameter protocol: PARAM_REQUEST_LIST, PARAM_REQUEST_READ, PARAM_SET -> PARAM_VALUE.

PX4 conventions: INT32 values travel *bytewise* in the float field (AUTOPILOT_VERSION announces
PARAM_ENCODE_BYTEWISE), every PARAM_VALUE carries the parameter's index and the total count, and a
PARAM_SET is echoed with the same type and value (or the unchanged value plus a STATUSTEXT reason when it
is refused: out of range, not finite) — without an echo MAVSDK retries five times and fails. A PARAM_SET whose
type is not the parameter's is ignored, as PX4 ignores it (a STATUSTEXT says why). A full list is paced out over a few
server iterations so a burst never overflows a ground station's socket buffer.
"""

from __future__ import annotations

import logging
import struct
import threading
from collections import deque
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import CommandResult
from harness.autopilot.mavlink.messages import MAVLinkMessage, Origin, Out, text_of
from harness.autopilot.params import ParamDef, Params, ParamType
from harness.autopilot.services import System

log = logging.getLogger(__name__)

_INT_TYPES = {
    mavlink2.MAV_PARAM_TYPE_UINT8: "<B",
    mavlink2.MAV_PARAM_TYPE_INT8: "<b",
    mavlink2.MAV_PARAM_TYPE_UINT16: "<H",
    mavlink2.MAV_PARAM_TYPE_INT16: "<h",
    mavlink2.MAV_PARAM_TYPE_UINT32: "<I",
    mavlink2.MAV_PARAM_TYPE_INT32: "<i",
}

_TYPE_NAMES = {
    v: k.removeprefix("MAV_PARAM_TYPE_")
    for k, v in vars(mavlink2).items()
    if k.startswith("MAV_PARAM_TYPE_") and k != "MAV_PARAM_TYPE_ENUM_END" and isinstance(v, int)
}


def encode_value(value: float, ptype: int) -> float:
    """The float to put in ``param_value``: INT32 bit pattern reinterpreted as a float32 (bytewise)."""
    if ptype == mavlink2.MAV_PARAM_TYPE_INT32:
        v: float = struct.unpack("<f", struct.pack("<i", int(value)))[0]
        return v
    return float(value)


def decode_value(raw: float, ptype: int) -> float:
    """The number a ``param_value`` field means for ``ptype`` (bytewise for integer types)."""
    fmt = _INT_TYPES.get(ptype)
    if fmt is None:
        return float(raw)
    data = struct.pack("<f", raw)
    size = struct.calcsize(fmt)
    n: int = struct.unpack(fmt, data[:size])[0]
    return float(n)


class ParamTable:
    """Ordered names and types of the autopilot's parameters; values read and written through the API.

    The autopilot's registry (``system.params``) gives the names and the order.
    """

    def __init__(self, api: System, bytewise: bool = True) -> None:
        self.api = api
        self.bytewise = bytewise
        """INT32 values bytewise in the float (PX4); False: the value cast to float (ArduPilot's C cast)."""
        self.registry: Params = api.params
        self.defs: tuple[ParamDef, ...] = tuple(self.registry.defs)
        self._index = {d.name: i for i, d in enumerate(self.defs)}

    def __len__(self) -> int:
        return len(self.defs)

    def index(self, name: str) -> int:
        return self._index.get(name, -1)

    def mav_type(self, index: int) -> int:
        t = self.defs[index].type
        return mavlink2.MAV_PARAM_TYPE_INT32 if t == ParamType.INT32 else mavlink2.MAV_PARAM_TYPE_REAL32

    def value_message(self, mav: mavlink2.MAVLink, index: int) -> MAVLinkMessage:
        d = self.defs[index]
        ptype = self.mav_type(index)
        value = self.api.params.get(d.name)
        raw = encode_value(value, ptype) if self.bytewise else float(value)
        return mav.param_value_encode(d.name.encode(), raw, ptype, len(self.defs), index)


@dataclass(slots=True)
class _ListJob:
    to: Origin
    next_index: int = 0


class ParamService:
    """Answers the parameter protocol for one autopilot. Server thread only."""

    def __init__(self, api: System, mav: mavlink2.MAVLink, per_tick: int = 40, bytewise: bool = True) -> None:
        self.table = ParamTable(api, bytewise)
        self.api = api
        self.mav = mav
        self.per_tick = per_tick
        self._jobs: deque[_ListJob] = deque()
        self._changed: list[str] = []
        self._changed_lock = threading.Lock()
        if self.table.registry is not None:
            self.table.registry.subscribe(self._on_change)

    def _on_change(self, name: str, _value: float) -> None:
        with self._changed_lock:
            if name not in self._changed:
                self._changed.append(name)

    def handle(self, m: MAVLinkMessage, origin: Origin) -> tuple[list[Out], CommandResult | None]:
        """Replies to one parameter message, and a refusal to report (PARAM_SET out of range...)."""
        mid = m.get_msgId()
        if mid == mavlink2.MAVLINK_MSG_ID_PARAM_REQUEST_LIST:
            self._jobs = deque(j for j in self._jobs if j.to.addr != origin.addr or j.to.link != origin.link)
            self._jobs.append(_ListJob(origin))
            return [], None
        if mid == mavlink2.MAVLINK_MSG_ID_PARAM_REQUEST_READ:
            index = m.param_index
            if index < 0:
                index = self.table.index(text_of(m.param_id))
            if not 0 <= index < len(self.table):
                log.debug("PARAM_REQUEST_READ for unknown %r / %d", text_of(m.param_id), m.param_index)
                return [], None
            return [Out(self.table.value_message(self.mav, index), origin)], None
        if mid == mavlink2.MAVLINK_MSG_ID_PARAM_SET:
            return self._set(m, origin)
        return [], None

    def _set(self, m: MAVLinkMessage, origin: Origin) -> tuple[list[Out], CommandResult | None]:
        name = text_of(m.param_id)
        index = self.table.index(name)
        if index < 0:
            return [], CommandResult.denied(f"PARAM_SET: unknown parameter {name!r}")
        if self.table.bytewise and m.param_type != self.table.mav_type(index):
            # PX4 (mavlink_parameters.cpp): "param types mismatch", nothing set and nothing sent back — a UINT8
            # 3 for a REAL32 parameter is not read as the float whose bits are 3. ArduPilot takes any type (its
            # value is always a float, the type a hint): ``bytewise`` False.
            want = _TYPE_NAMES.get(self.table.mav_type(index), "?")
            got = _TYPE_NAMES.get(m.param_type, str(m.param_type))
            return [], CommandResult.denied(f"PARAM_SET {name}: {got} is not {want}")
        value = decode_value(m.param_value, m.param_type) if self.table.bytewise else float(m.param_value)
        result = self.api.params.set(name, value)
        # Echo (new or unchanged value) to everyone, like PX4: the sender sees its confirmation.
        with self._changed_lock:
            if name in self._changed:
                self._changed.remove(name)
        return [Out(self.table.value_message(self.mav, index), None)], (None if result.ok else result)

    def tick(self) -> list[Out]:
        """Paced list transfers and PARAM_VALUE for changes made inside the autopilot."""
        out: list[Out] = []
        with self._changed_lock:
            changed, self._changed = self._changed, []
        for name in changed:
            i = self.table.index(name)
            if i >= 0:
                out.append(Out(self.table.value_message(self.mav, i), None))
        budget = self.per_tick
        while self._jobs and budget > 0:
            job = self._jobs[0]
            while job.next_index < len(self.table) and budget > 0:
                out.append(Out(self.table.value_message(self.mav, job.next_index), job.to))
                job.next_index += 1
                budget -= 1
            if job.next_index >= len(self.table):
                self._jobs.popleft()
        return out

    @property
    def busy(self) -> bool:
        return bool(self._jobs)
