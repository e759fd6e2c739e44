"""MAVLink 2 codec: encode outgoing messages (sequence, optional signing) and decode datagrams.

A thin, pure layer over pymavlink's generated ``common`` dialect: frames are built by precompiled packers
(``packers.py``, byte for byte pymavlink's frames), pymavlink's encoder makes the rest and every decode.
Each UDP datagram is decoded on its own
(a garbage datagram can never swallow the start of the next one), every frame is classified (good,
malformed, unknown id, unsigned, badly signed) and nothing here ever raises on bad input.

Signing follows the MAVLink 2 message-signing spec: SHA-256 over ``key + frame without the 6 signature
bytes``, first 6 bytes; a 48-bit timestamp in units of 10 µs since 2015-01-01 that must increase per
stream ``(link id, sysid, compid)``; a new stream is accepted when its timestamp is at most one minute
behind ours. The verification is done here (not inside pymavlink) so that unsigned and badly signed frames
can be told apart and counted separately.
"""

from __future__ import annotations

import enum
import hashlib
import hmac
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeAlias

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.mavlink.packers import FrameEncoder, Signer
from harness.core.errors import ScenarioError

MAVLinkMessage: TypeAlias = mavlink2.MAVLink_message  # pymavlink is untyped: this is Any to mypy

_SIGNING_EPOCH_UNIX_NS = 1_420_070_400 * 1_000_000_000
"""2015-01-01T00:00:00Z, the origin of MAVLink 2 signing timestamps."""
_SIG_TICK_NS = 10_000
_NEW_STREAM_MAX_LAG = 6_000_000
"""One minute in signing-timestamp units (10 µs)."""


@dataclass(frozen=True, slots=True)
class SigningConfig:
    """MAVLink 2 signing: a 32-byte secret key shared with the ground stations and scripts."""

    key: bytes
    link_id: int = 0
    sign_outgoing: bool = True

    def __post_init__(self) -> None:
        if len(self.key) != 32:
            raise ScenarioError(
                f"MAVLink signing key must be 32 bytes, got {len(self.key)}: give 64 hex digits or a passphrase"
            )
        if not 0 <= self.link_id <= 255:
            raise ScenarioError(f"MAVLink signing link_id must be in 0..255, got {self.link_id}")

    @classmethod
    def from_passphrase(cls, passphrase: str, link_id: int = 0) -> SigningConfig:
        """The key MAVProxy's ``signing setup PASSPHRASE`` derives: SHA-256 of the passphrase."""
        return cls(hashlib.sha256(passphrase.encode()).digest(), link_id)

    @classmethod
    def from_hex(cls, key_hex: str, link_id: int = 0) -> SigningConfig:
        try:
            key = bytes.fromhex(key_hex)
        except ValueError as e:
            raise ScenarioError(f"MAVLink signing key {key_hex!r} is not hexadecimal: {e}") from None
        return cls(key, link_id)


class FrameStatus(enum.Enum):
    OK = "ok"
    MALFORMED = "malformed"
    """Bad prefix, length, CRC, truncated or an undecodable payload."""
    UNKNOWN = "unknown"
    """Well formed but a message id outside the common dialect."""
    UNSIGNED = "unsigned"
    """Signing is required and the frame carries no signature."""
    BAD_SIGNATURE = "bad_signature"
    """Wrong key, replayed or stale timestamp."""


@dataclass(slots=True)
class Decoded:
    status: FrameStatus
    message: MAVLinkMessage | None = None
    detail: str = ""


def signing_timestamp(unix_ns: int) -> int:
    """A MAVLink 2 signing timestamp (10 µs units since 2015-01-01) for a Unix time in ns."""
    return max(0, (unix_ns - _SIGNING_EPOCH_UNIX_NS) // _SIG_TICK_NS)


@dataclass(slots=True)
class _SignatureState:
    key: bytes
    timestamp: int
    stream_timestamps: dict[tuple[int, int, int], int] = field(default_factory=dict)


def verify_signature(frame: bytes | bytearray, state: _SignatureState) -> bool:
    """Check the signature block of a complete signed MAVLink 2 frame; updates the stream timestamps."""
    if len(frame) < 10 + 2 + 13:
        return False
    link_id = frame[-13]
    timestamp = int.from_bytes(frame[-12:-6], "little")
    stream = (link_id, frame[5], frame[6])
    last = state.stream_timestamps.get(stream)
    if last is not None:
        if timestamp <= last:
            return False
    elif timestamp + _NEW_STREAM_MAX_LAG < state.timestamp:
        return False
    expected = hashlib.sha256(state.key + bytes(frame[:-6])).digest()[:6]
    if not hmac.compare_digest(expected, bytes(frame[-6:])):
        return False
    state.stream_timestamps[stream] = timestamp
    state.timestamp = max(state.timestamp, timestamp)
    return True


class Codec:
    """Encoder and decoder for one system (sysid, compid). Not thread-safe: one owner thread."""

    def __init__(
        self,
        sysid: int,
        compid: int = 1,
        signing: SigningConfig | None = None,
        unix_time_ns: Callable[[], int] | None = None,
    ) -> None:
        if not 1 <= sysid <= 255:
            raise ScenarioError(f"MAVLink system id must be in 1..255, got {sysid}")
        self.sysid = sysid
        self.compid = compid
        self._enc = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self._dec = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self._dec.robust_parsing = True
        self._sig: _SignatureState | None = None
        self.signing = signing
        signer = None
        if signing is not None:
            if unix_time_ns is None:
                raise ScenarioError("MAVLink signing needs a wall clock (unix_time_ns) for its timestamps")
            self._sig = _SignatureState(signing.key, signing_timestamp(unix_time_ns()))
            if signing.sign_outgoing:
                clock = unix_time_ns
                signer = Signer(signing.key, signing.link_id, lambda: signing_timestamp(clock()))
        self._frames = FrameEncoder(sysid, compid, self._enc, signer)

    @property
    def mav(self) -> mavlink2.MAVLink:
        """The pymavlink object whose ``*_encode`` methods build messages (never used to send; its sequence
        number and signing timestamp are the encoder's only while it frames a message without a packer)."""
        return self._enc

    def encode(self, msg: MAVLinkMessage) -> bytes:
        """One MAVLink 2 frame with the next sequence number (signed when configured): the message's
        precompiled packer (``packers.py``), or pymavlink's encoder for a message without one."""
        return self._frames.encode(msg)

    @property
    def fallback_frames(self) -> int:
        """Frames encoded so far by pymavlink's encoder instead of a precompiled packer."""
        return self._frames.fallback_frames

    def decode(self, datagram: bytes) -> list[Decoded]:
        """Every frame of one datagram, classified. Never raises."""
        dec = self._dec
        dec.buf = bytearray()
        dec.buf_index = 0
        dec.expected_length = mavlink2.HEADER_LEN_V1 + 2
        dec.have_prefix_error = False
        out: list[Decoded] = []
        try:
            msgs = dec.parse_buffer(datagram) or []
        except Exception as e:  # pymavlink raises a few odd errors on hostile input
            return [Decoded(FrameStatus.MALFORMED, None, f"parser error: {e}")]
        for m in msgs:
            out.append(self._classify(m))
        if dec.buf_len() > 0:
            out.append(Decoded(FrameStatus.MALFORMED, None, f"truncated frame ({dec.buf_len()} bytes left)"))
        return out

    def _classify(self, m: MAVLinkMessage) -> Decoded:
        if isinstance(m, mavlink2.MAVLink_bad_data):
            return Decoded(FrameStatus.MALFORMED, None, str(getattr(m, "reason", "bad data")))
        if self._sig is not None:
            frame = m.get_msgbuf()
            signed = frame[0] == mavlink2.PROTOCOL_MARKER_V2 and (frame[2] & mavlink2.MAVLINK_IFLAG_SIGNED) != 0
            if not signed:
                return Decoded(FrameStatus.UNSIGNED, m, "unsigned frame while signing is required")
            if not verify_signature(frame, self._sig):
                return Decoded(FrameStatus.BAD_SIGNATURE, m, "bad signature or stale timestamp")
        if isinstance(m, mavlink2.MAVLink_unknown):  # (its CRC cannot be checked: no CRC_EXTRA for the id)
            return Decoded(FrameStatus.UNKNOWN, m, f"unknown message id {m.get_msgId()}")
        return Decoded(FrameStatus.OK, m)
