"""The channel protocol: every message of the lockstep tick, one codec, one framing.

This module is the whole wire protocol between the channel (the paper's GZUAVCHANNEL) and its peers:
the physics process that owns the clock, autopilots, type-0 subscribers (mission processes), type-1
subscribers (network simulators, recorders) and child channels in a tree.

Framing: every frame is a 4-byte big-endian unsigned length followed by that many bytes of msgpack.
The msgpack body is one message, encoded as an array whose first element is the message's tag (see
``msgspec`` tagged unions with ``array_like=True``). The codec is pure: :func:`encode` turns a message
into a frame, :class:`FrameDecoder` turns a byte stream back into messages and raises
:class:`ProtocolError` on anything malformed. No sockets here.

Time is an integer count of nanoseconds of simulated time (``t_ns``) everywhere.

Handshake (one round trip and a half, on every new connection)::

    channel -> peer   CHALLENGE(version, nonce)
    peer -> channel   HELLO(version, kind, name, vehicles, auth)        # the paper's *subscription*
    channel -> peer   WELCOME(peer_id, epoch_ns, tick_ns)    or   ERROR(...) and close

``auth`` is HMAC-SHA256(secret, nonce || name) when the channel requires a shared secret, else empty.

One tick (see docs/design.md, "The tick")::

    physics  -> channel   BEGIN-TICK-AC(t, vehicle, ...)  one per vehicle     (BeginTickAC)
    channel  -> autopilot BEGIN-TICK-AC                                        (forwarded)
    channel  -> type 0    BEGIN-TICK-0(t)                  phase 0 starts      (BeginTick0)
    type 0   -> channel   ENQUEUE(...)*  then  END-TICK-0(t)                   (Enqueue, EndTick0)
    autopilot-> channel   END-TICK-AC(t, vehicle, motors)                      (EndTickAC)
    channel  -> type 1    BEGIN-TICK-1(t, positions, packets)  phase 1 starts  (BeginTick1)
    type 1   -> channel   DELIVER(...)*  then  END-TICK-1(t)                   (Deliver or DeliverMany, EndTick1)
    channel  -> type 0    DELIVER (routed to the addressed vehicle's missions)
    channel  -> physics   END-TICK-AC for every vehicle                        (forwarded)

A child channel (tree of channels, paper section III-C) connects to its parent with kind CHILD and is
treated by the parent as an autopilot host for the vehicles it announces *and* as a type-0 and type-1
subscriber: it receives BEGIN-TICK-AC, BEGIN-TICK-0 and BEGIN-TICK-1 and answers END-TICK-AC,
END-TICK-0 and END-TICK-1 for its whole subtree, and relays ENQUEUE up and DELIVER in both directions.
"""

from __future__ import annotations

import enum
import hashlib
import hmac
import struct
from typing import Annotated, Final, NamedTuple, Protocol

import msgspec

from harness.core.geo import Vec3

PROTOCOL_VERSION: Final = 4
"""Bumped on every incompatible change of a message below (3: END-TICK-AC carries ``ticks``; 4: its status is
64 bits, with the gimbal's attitude, and each tick record 145 bytes)."""

MAX_FRAME_BYTES: Final = 16 * 1024 * 1024
"""Frames larger than this are refused as malformed (a garbage length prefix must not allocate GBs)."""

MAX_HELLO_BYTES: Final = 64 * 1024
"""Limit on a frame from a peer that has not been admitted yet (its HELLO): an unauthenticated connection
holds at most this much of the channel's memory. A HELLO of an autopilot holding 20,000 vehicles fits."""

BROADCAST: Final = -1
"""Destination vehicle of a broadcast packet."""

EVERY_PHASE: Final = 0
"""``idle_until_ns`` of a subscriber that takes part in every phase (the default)."""
NO_DEADLINE: Final = 1 << 62
"""``idle_until_ns`` of a subscriber with no timed wait: only a WAKE (or a DELIVER it waits for) needs it."""
MAVLINK_UNKNOWN: Final = -1
"""END-TICK-AC ``mavlink`` of an autopilot that does not say whether it sent its missions MAVLink (a subscriber
that waits for its vehicle's MAVLink then takes part in every phase)."""

_LEN = struct.Struct(">I")


class ProtocolError(Exception):
    """A frame or message that does not follow this protocol."""


class PeerKind(enum.IntEnum):
    """What a peer is, declared in its HELLO (the paper's subscription type, and more)."""

    TYPE0 = 0
    """Type-0 subscriber: runs *inside* the simulated world, in phase 0 (mission processes)."""
    TYPE1 = 1
    """Type-1 subscriber: simulates part of the world, in phase 1 (network simulator, recorder)."""
    PHYSICS = 2
    """The clock owner: emits BEGIN-TICK-AC and waits for END-TICK-AC (the paper's Gazebo plugin)."""
    AUTOPILOT = 3
    """Holds the flight stacks of ``vehicles``: answers BEGIN-TICK-AC with END-TICK-AC."""
    CHILD = 4
    """A child channel of a tree; holds ``vehicles`` and relays both phases for its subtree."""


class ErrorCode(enum.IntEnum):
    """Why an ERROR frame was sent."""

    BAD_VERSION = 1
    BAD_AUTH = 2
    MALFORMED = 3
    UNEXPECTED = 4
    STALLED = 5
    PEER_LOST = 6
    ROUTING = 7
    SHUTDOWN = 8
    INTERNAL = 9


class _Msg(msgspec.Struct, array_like=True, frozen=True, tag_field="tag"):
    """Base of every message; the tag is the first element of the encoded array."""


# --- handshake -------------------------------------------------------------------------------


class Challenge(_Msg, tag="CHALLENGE", frozen=True):
    """Channel -> peer, first frame on a connection: protocol version and a nonce for the secret."""

    version: int
    nonce: bytes


class Hello(_Msg, tag="HELLO", frozen=True):
    """Peer -> channel: the subscription (paper: "subscription, specifying its type").

    ``vehicle`` is the vehicle a type-0 subscriber belongs to (-1 for none); ``vehicles`` are the
    vehicles an AUTOPILOT or CHILD holds, or that PHYSICS simulates.
    """

    version: int
    kind: PeerKind
    name: str
    vehicle: int = -1
    vehicles: tuple[int, ...] = ()
    auth: bytes = b""


class Welcome(_Msg, tag="WELCOME", frozen=True):
    """Channel -> peer: subscription accepted. ``epoch_ns`` is the Unix time of sim time zero."""

    peer_id: int
    epoch_ns: int
    phase_period_ns: int


class Announce(_Msg, tag="ANNOUNCE", frozen=True):
    """CHILD/AUTOPILOT -> channel: what it holds has changed (a late autopilot or subscriber joined or left)."""

    vehicles: tuple[int, ...]
    mission_vehicles: tuple[int, ...] = ()
    members: int = 0  # admitted subscribers below the sender, counted through its own children
    exits: tuple[tuple[str, int, int, str], ...] = ()
    """Every mission that ended below the sender so far: (name, vehicle, exit code, reason), oldest first."""


# --- the tick ----------------------------------------------------------------------------------


class BeginTickAC(_Msg, tag="BTA", frozen=True):
    """BEGIN-TICK-AC: physics -> channel -> autopilot, one per vehicle and tick.

    ``count`` is how many BEGIN-TICK-AC the *recipient* gets for this tick (the channel rewrites it
    when it splits a tick among autopilots and children). ``position_ned_m`` is the vehicle's true
    position in the world NED frame, which the channel hands to type-1 subscribers in BEGIN-TICK-1.
    ``frame`` is the vehicle's sensor frame, opaque to the channel (codec in ``harness.fdm.frame``).
    """

    t_ns: int
    tick: int
    vehicle: int
    count: int
    position_ned_m: Vec3
    frame: bytes = b""


class EndTickAC(_Msg, tag="ETA", frozen=True):
    """END-TICK-AC: autopilot -> channel -> physics: the motor commands for the next interval.

    ``motors`` are normalised commands in [0, 1] in PX4 quad-X motor order; physics validates them.
    ``status`` is the autopilot's state for recording, packed by :func:`pack_status`.
    ``ticks``: empty, or — from a host that steps the vehicle's physics itself (``harness run --workers``) —
    what happened to the vehicle at each tick since its previous END-TICK-AC, oldest first, the last at
    ``t_ns``: ground truth, motors and status, :func:`pack_tick` records back to back. The channel hands the
    last one's position to type-1 subscribers instead of the BEGIN-TICK-AC's.
    ``mavlink``: 1 when the vehicle sent MAVLink to a mission on sim time (a socket that announced itself to it)
    since its previous END-TICK-AC that said, 0 when it sent none, :data:`MAVLINK_UNKNOWN` when it does not say
    (our autopilots say at the ticks with phases): until a vehicle has said, the channel wakes its mission at every
    phase if the mission waits for its vehicle's MAVLink (END-TICK-0 ``mavlink_wakes``).
    ``events``: empty, or what the vehicle's autopilot tells the physics and the recordings
    (``harness.autopilot.events``): changes of its simulated world (ArduPilot's ``SIM_*``), applied before the
    physics step after ``t_ns`` by whoever steps the vehicle's physics (a host that does reports those it
    applied), and its camera's pictures.
    """

    t_ns: int
    vehicle: int
    motors: tuple[float, ...]
    status: int = 0
    ticks: bytes = b""
    mavlink: int = MAVLINK_UNKNOWN
    events: bytes = b""

    def __post_init__(self) -> None:  # also on decoding: a malformed record is a malformed frame
        if len(self.ticks) % TICK_BYTES:
            raise ValueError(f"END-TICK-AC ticks of {len(self.ticks)} bytes, not a multiple of {TICK_BYTES}")


_TICK = struct.Struct("<13dB4dQ")
TICK_BYTES: Final = _TICK.size
_POS = struct.Struct("<3d")


class TruthReport(NamedTuple):
    """A vehicle's ground truth as END-TICK-AC carries it (field names as ``harness.fdm.frame.Truth``)."""

    pos_ned_m: Vec3
    vel_ned_m_s: Vec3
    quat: tuple[float, float, float, float]
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    on_ground: bool
    crashed: bool


class TruthLike(Protocol):
    """What :func:`pack_tick` reads: a :class:`TruthReport` or ``harness.fdm.frame.Truth``."""

    @property
    def pos_ned_m(self) -> Vec3: ...
    @property
    def vel_ned_m_s(self) -> Vec3: ...
    @property
    def quat(self) -> tuple[float, float, float, float]: ...
    @property
    def lat_deg(self) -> float: ...
    @property
    def lon_deg(self) -> float: ...
    @property
    def alt_amsl_m(self) -> float: ...
    @property
    def on_ground(self) -> bool: ...
    @property
    def crashed(self) -> bool: ...


class TickReport(NamedTuple):
    """One tick of a vehicle simulated by an autopilot host: its truth, then its autopilot's answer."""

    truth: TruthReport
    motors: tuple[float, float, float, float]
    status: int


def pack_tick(truth: TruthLike, motors: tuple[float, ...], status: int) -> bytes:
    """One record of END-TICK-AC ``ticks``: 13 little-endian doubles of truth (every bit kept), a flags
    byte, 4 doubles of motors and the status (64 bits), 145 bytes."""
    flags = (1 if truth.on_ground else 0) | (2 if truth.crashed else 0)
    return _TICK.pack(
        *truth.pos_ned_m, *truth.vel_ned_m_s, *truth.quat, truth.lat_deg, truth.lon_deg, truth.alt_amsl_m, flags,
        *motors, status
    )  # fmt: skip


def unpack_ticks(data: bytes) -> list[TickReport]:
    """The records :func:`pack_tick` packed, oldest first."""
    # the root unpacks every tick of every vehicle of its autopilot hosts: the tuples are built directly
    # (``tuple.__new__``), without the Python-level ``__new__`` a NamedTuple call runs
    new, truth_report, tick_report = tuple.__new__, TruthReport, TickReport
    return [
        new(
            tick_report,
            (
                new(
                    truth_report,
                    ((pn, pe, pd), (vn, ve, vd), (qw, qx, qy, qz), lat, lon, alt, flags & 1 == 1, flags & 2 == 2),
                ),
                (m0, m1, m2, m3),
                status,
            ),
        )
        for pn, pe, pd, vn, ve, vd, qw, qx, qy, qz, lat, lon, alt, flags, m0, m1, m2, m3, status in _TICK.iter_unpack(
            data
        )
    ]


def last_position(ticks: bytes) -> Vec3:
    """The NED position in the last record of END-TICK-AC ``ticks`` (what the channel needs for BEGIN-TICK-1)."""
    x, y, z = _POS.unpack_from(ticks, len(ticks) - TICK_BYTES)
    return (x, y, z)


STATUS_ARMED: Final = 1
"""The armed bit of an END-TICK-AC ``status`` (``status & STATUS_ARMED``: what the root reads at every tick)."""
STATUS_GIMBAL: Final = 1 << 24
"""Set when the status carries a gimbal's attitude (:func:`unpack_gimbal`); never for a vehicle whose gimbal
nobody used, whose status is then what it was without gimbals."""
_GIMBAL_MDEG_PER_DEG: Final = 1000
_PITCH_BITS, _YAW_BITS = 18, 19


def pack_status(
    armed: bool, landed_state: int, main_mode: int, sub_mode: int, gimbal: tuple[float, float] | None = None
) -> int:
    """END-TICK-AC ``status``: bit 0 armed, bits 1-3 MAV_LANDED_STATE, 8-15 PX4 main mode, 16-23 sub mode;
    with a ``gimbal`` (pitch earth-stabilised in [-90, 90], yaw relative to the heading in [-180, 180], degrees)
    bit 24 (:data:`STATUS_GIMBAL`), then the pitch + 90 (bits 25-42) and the yaw + 180 (bits 43-61) in
    thousandths of a degree. Below 2**62: one integer of every msgspec and ``struct`` codec."""
    status = (
        (STATUS_ARMED if armed else 0)
        | ((landed_state & 0x7) << 1)
        | ((main_mode & 0xFF) << 8)
        | ((sub_mode & 0xFF) << 16)
    )
    if gimbal is None:
        return status
    pitch, yaw = gimbal
    k = _GIMBAL_MDEG_PER_DEG
    pitch_m = min(max(round((pitch + 90.0) * k), 0), 180 * k)
    yaw_m = min(max(round((yaw + 180.0) * k), 0), 360 * k)
    return status | STATUS_GIMBAL | (pitch_m << 25) | (yaw_m << (25 + _PITCH_BITS))


def unpack_gimbal(status: int) -> tuple[float, float] | None:
    """(pitch, yaw relative to the heading) in degrees from an END-TICK-AC ``status``; None without a gimbal."""
    if not status & STATUS_GIMBAL:
        return None
    k = _GIMBAL_MDEG_PER_DEG
    pitch_m = (status >> 25) & ((1 << _PITCH_BITS) - 1)
    yaw_m = (status >> (25 + _PITCH_BITS)) & ((1 << _YAW_BITS) - 1)
    return (pitch_m - 90 * k) / k, (yaw_m - 180 * k) / k


def unpack_status(status: int) -> tuple[bool, int, int, int]:
    """(armed, landed_state, main_mode, sub_mode) from an END-TICK-AC ``status``."""
    return status & STATUS_ARMED != 0, (status >> 1) & 0x7, (status >> 8) & 0xFF, (status >> 16) & 0xFF


class BeginTick0(_Msg, tag="BT0", frozen=True):
    """BEGIN-TICK-0: channel -> type-0 subscribers: phase 0 of tick ``tick`` at sim time ``t_ns``."""

    t_ns: int
    tick: int


class EndTick0(_Msg, tag="ET0", frozen=True):
    """END-TICK-0: type-0 subscriber -> channel: idle until the next phase 0.

    Lookahead (optional): ``idle_until_ns`` is the earliest sim time the subscriber must run again (its
    next timed wait); until then the channel leaves it out of phase 0, unless it sends WAKE or, when
    ``deliver_wakes``, a DELIVER for it arrives. :data:`EVERY_PHASE` (the default): every phase 0, as in
    the paper; :data:`NO_DEADLINE`: no timed wait at all. Its script still never runs outside phase 0 and
    every wait ends at the same phase as without lookahead; only idle phases are skipped.
    ``mavlink_wakes``: the subscriber also waits for its vehicle's MAVLink (MAVSDK's threads read their sockets):
    the channel wakes it at the phases after which its vehicle said it sent it some (END-TICK-AC ``mavlink``), and
    at every phase while the vehicle does not say.
    """

    t_ns: int
    idle_until_ns: int = EVERY_PHASE
    deliver_wakes: bool = True
    mavlink_wakes: bool = False


class Packet(msgspec.Struct, array_like=True, frozen=True):
    """A network packet as handed to the network simulator (body of ENQUEUE and BEGIN-TICK-1)."""

    t_ns: int
    src: int
    dst: int
    port: int
    seq: int
    payload: bytes


class VehiclePosition(msgspec.Struct, array_like=True, frozen=True):
    vehicle: int
    ned_m: Vec3


class Enqueue(_Msg, tag="ENQ", frozen=True):
    """ENQUEUE-NS3: type-0 -> channel, in phase 0: a packet for the network; only queued."""

    packet: Packet


class BeginTick1(_Msg, tag="BT1", frozen=True):
    """BEGIN-TICK-1: channel -> type-1: simulate [t, t + period) with these positions and packets."""

    t_ns: int
    tick: int
    period_ns: int
    positions: tuple[VehiclePosition, ...]
    packets: tuple[Packet, ...]


class Deliver(_Msg, tag="DLV", frozen=True):
    """DELIVER: type-1 -> channel -> type-0 of vehicle ``packet.dst``: a packet received at ``at_ns``."""

    at_ns: int
    packet: Packet
    rssi_dbm: float = 0.0


class DeliverMany(_Msg, tag="DLVS", frozen=True):
    """Several DELIVERs for the missions of one vehicle ``dst`` in one frame: a network simulator groups the
    arrivals of an interval by receiver, so a swarm's broadcasts cost one frame per receiver, not per packet."""

    dst: int
    delivers: tuple[Deliver, ...]


class EndTick1(_Msg, tag="ET1", frozen=True):
    """END-TICK-1: type-1 -> channel: the interval is simulated, every DELIVER of it was sent.

    ``idle_until_ns`` (optional lookahead): nothing is in flight before this sim time, so the channel may
    leave the subscriber out of phase 1 until then, unless a phase 0 enqueues packets. A model whose own
    events run between packets (ns-3) keeps the default :data:`EVERY_PHASE`.
    """

    t_ns: int
    idle_until_ns: int = EVERY_PHASE


class Wake(_Msg, tag="WAKE", frozen=True):
    """WAKE: type-0 -> channel, between phases: something arrived for the script on the wall clock (a
    socket, another thread) while it was left out of phase 0; include it in the next phase 0."""


# --- control -----------------------------------------------------------------------------------


class Bye(_Msg, tag="BYE", frozen=True):
    """Either direction: an orderly leave. A mission reports its exit code here."""

    reason: str = ""
    exit_code: int = 0


class Error(_Msg, tag="ERR", frozen=True):
    """Either direction: something went wrong. ``fatal`` errors end the run."""

    code: ErrorCode
    message: str
    fatal: bool = False


Message = Annotated[
    Challenge
    | Hello
    | Welcome
    | Announce
    | BeginTickAC
    | EndTickAC
    | BeginTick0
    | EndTick0
    | Enqueue
    | BeginTick1
    | Deliver
    | DeliverMany
    | EndTick1
    | Wake
    | Bye
    | Error,
    "any channel message",
]

_encoder = msgspec.msgpack.Encoder()
_decoder: msgspec.msgpack.Decoder[Message] = msgspec.msgpack.Decoder(Message)


def encode(msg: Message) -> bytes:
    """One message as one frame: length prefix plus msgpack body."""
    body = _encoder.encode(msg)
    return _LEN.pack(len(body)) + body


def encode_many(msgs: list[Message]) -> bytes:
    """Several frames back to back (one socket write for a burst)."""
    return b"".join(encode(m) for m in msgs)


def decode_body(body: bytes | memoryview) -> Message:
    """Decode one frame body; :class:`ProtocolError` if it is not a valid message."""
    try:
        return _decoder.decode(body)
    except (msgspec.DecodeError, msgspec.ValidationError, ValueError, TypeError) as exc:
        raise ProtocolError(f"malformed message: {exc}") from None


class FrameDecoder:
    """Incremental decoder: feed bytes as they arrive, get whole messages out."""

    __slots__ = ("_buf", "max_frame")

    def __init__(self, max_frame: int = MAX_FRAME_BYTES) -> None:
        self._buf = bytearray()
        self.max_frame = max_frame

    def feed(self, data: bytes) -> list[Message]:
        """Append ``data`` and return every message now complete (possibly none)."""
        buf = self._buf
        buf += data
        out: list[Message] = []
        pos = 0
        n = len(buf)
        while n - pos >= 4:
            (size,) = _LEN.unpack_from(buf, pos)
            if size > self.max_frame:
                raise ProtocolError(f"frame of {size} bytes exceeds the limit of {self.max_frame}")
            end = pos + 4 + size
            if end > n:
                break
            out.append(decode_body(memoryview(buf)[pos + 4 : end]))
            pos = end
        if pos:
            del buf[:pos]
        return out

    @property
    def pending(self) -> int:
        """Bytes received but not yet part of a whole frame."""
        return len(self._buf)


def auth_token(secret: bytes, nonce: bytes, name: str) -> bytes:
    """The HELLO ``auth`` field for a channel that requires ``secret``."""
    return hmac.new(secret, nonce + name.encode(), hashlib.sha256).digest()


def check_auth(secret: bytes, nonce: bytes, name: str, auth: bytes) -> bool:
    return hmac.compare_digest(auth_token(secret, nonce, name), auth)
