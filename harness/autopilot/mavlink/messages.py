"""Shared pieces of the MAVLink services: where a message came from, what to send where, field helpers.

Services are pure: they take a decoded message (or the time) and return ``Out`` items; the server (the
thin shell) encodes and sends them. ``Out.to = None`` means every link and live peer (telemetry,
STATUSTEXT, parameter echoes); otherwise it is the origin the reply goes back to.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import Severity
from harness.autopilot.mavlink.codec import MAVLinkMessage
from harness.autopilot.mavlink.transport import Address

INT32_MAX = 2**31 - 1
UINT16_MAX = 0xFFFF


@dataclass(frozen=True, slots=True)
class Origin:
    """The link (by index in the server's list) and the address a message came from."""

    link: int
    addr: Address
    sysid: int
    compid: int


@dataclass(frozen=True, slots=True)
class Out:
    msg: MAVLinkMessage
    to: Origin | None = None
    wall_clock: bool = False
    """Sent only because wall time passed (the sim is slow or paused): not for peers that live on sim time."""
    compid: int = 0
    """Sent as this component of the vehicle's system (0: the autopilot's; the camera's is 100)."""


def clamp_int(value: float, lo: int, hi: int, default: int = 0) -> int:
    """``round(value)`` clamped to [lo, hi]; ``default`` for NaN/inf (a bad state never breaks packing)."""
    if not math.isfinite(value):
        return default
    return max(lo, min(hi, round(value)))


def finite(value: float, default: float = 0.0) -> float:
    return value if math.isfinite(value) else default


def is_set(value: float) -> bool:
    """MAVLink 'unset' convention for float command parameters: NaN means 'use the default / keep'."""
    return not math.isnan(value)


def text_of(raw: bytes | str) -> str:
    """A char[] field as text (pymavlink gives bytes or str depending on the field)."""
    if isinstance(raw, bytes):
        return raw.split(b"\x00", 1)[0].decode("utf-8", errors="replace")
    return raw.split("\x00", 1)[0]


_STATUSTEXT_LEN = 50


def statustext(mav: mavlink2.MAVLink, severity: Severity, text: str, chunk_id: int) -> list[MAVLinkMessage]:
    """STATUSTEXT message(s); text longer than 50 bytes is split into chunks sharing ``chunk_id``."""
    data = text.encode("utf-8", errors="replace")
    if len(data) <= _STATUSTEXT_LEN:
        return [mav.statustext_encode(int(severity), data, 0, 0)]
    chunks = [data[i : i + _STATUSTEXT_LEN] for i in range(0, len(data), _STATUSTEXT_LEN)]
    if len(chunks[-1]) == _STATUSTEXT_LEN:
        chunks.append(b"")  # a full last chunk needs an empty terminator so receivers know it ended
    cid = chunk_id & 0xFFFF or 1
    return [mav.statustext_encode(int(severity), c, cid, i) for i, c in enumerate(chunks[:256])]
