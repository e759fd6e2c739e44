"""The precompiled packers against pymavlink's encoder, the reference: for every message id of the two dialects
they cover, seeded random field values (extremes, zeros for the payload truncation, extension fields given or
left to their defaults) give byte-identical frames, unsigned and signed; the sequence number and the signing
timestamp run on across frames pymavlink makes (classes without a packer); and a vehicle's real traffic is all
packed here, every frame equal to pymavlink's encoding of the message it carries."""

from __future__ import annotations

import hashlib
import inspect
import itertools
from collections.abc import Callable, Iterator
from types import ModuleType
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega, common, minimal

from harness.autopilot.mavlink import SigningConfig
from harness.autopilot.mavlink.codec import Codec, FrameStatus, signing_timestamp
from harness.autopilot.mavlink.packers import FrameEncoder, Signer, crc16, crc16_stdlib, packer_for
from tests.autopilot.mavlink.conftest import Gcs, Rig

KEY = hashlib.sha256(b"packers").digest()
DIALECTS = (common, ardupilotmega)
SYSID, COMPID = 7, 1

_INT_RANGES = {
    "uint8_t": (0, 2**8 - 1),
    "int8_t": (-(2**7), 2**7 - 1),
    "uint16_t": (0, 2**16 - 1),
    "int16_t": (-(2**15), 2**15 - 1),
    "uint32_t": (0, 2**32 - 1),
    "int32_t": (-(2**31), 2**31 - 1),
    "uint64_t": (0, 2**64 - 1),
    "int64_t": (-(2**63), 2**63 - 1),
}
_SPECIAL_FLOATS = (0.0, -0.0, 1.0, float("inf"), float("-inf"), float("nan"), 1e-40, 3.0e38, -1.5)


def _scalar(rng: np.random.Generator, ftype: str, zero_p: float) -> int | float:
    if rng.random() < zero_p:
        return 0.0 if ftype in ("float", "double") else 0
    if ftype in ("float", "double"):
        r = rng.random()
        if r < 0.3:
            return float(_SPECIAL_FLOATS[int(rng.integers(len(_SPECIAL_FLOATS)))])
        return float(rng.normal() * 10.0 ** int(rng.integers(-6, 9)))
    lo, hi = _INT_RANGES[ftype]
    r = rng.random()
    if r < 0.15:
        return lo
    if r < 0.3:
        return hi
    return int(rng.integers(lo, hi, endpoint=True, dtype=np.int64 if lo < 0 else np.uint64))


def _field(rng: np.random.Generator, ftype: str, n: int, zero_p: float) -> Any:
    if ftype == "char":
        length = int(rng.integers(0, n + 4))  # longer than the field too: the struct cuts it
        raw = bytes(int(rng.integers(1, 256)) if rng.random() > zero_p / 3 else 0 for _ in range(length))
        return raw
    if not n:
        return _scalar(rng, ftype, zero_p)
    values = [_scalar(rng, ftype, zero_p) for _ in range(n + int(rng.integers(0, 3)))]  # extra elements ignored
    if ftype == "uint8_t" and rng.random() < 0.3:
        return bytes(int(v) for v in values)
    return tuple(values) if rng.random() < 0.5 else values


def random_message(cls: type, rng: np.random.Generator) -> Any:
    """A message of ``cls`` with random fields: mostly random, sometimes all zero, sometimes the extension
    fields (those after the base fields) left to pymavlink's defaults."""
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    zero_p = float(rng.choice([0.0, 0.3, 0.8, 1.0]))
    fields = {
        name: _field(rng, ftype, lengths[name], zero_p)
        for name, ftype in zip(cls.fieldnames, cls.fieldtypes, strict=True)
    }
    base = _base_fields(cls)
    if base < len(cls.fieldnames) and rng.random() < 0.3:
        for name in cls.fieldnames[base:]:
            del fields[name]
    return cls(**fields)


def _base_fields(cls: type) -> int:
    """How many fields come before the extensions: the constructor's parameters without a default."""
    params = list(inspect.signature(cls.__init__).parameters.values())[1:]
    return sum(1 for p in params if p.default is inspect.Parameter.empty)


def message_classes(dialect: ModuleType) -> list[type]:
    return [dialect.mavlink_map[i] for i in sorted(dialect.mavlink_map)]


class Reference:
    """pymavlink's encoder as the codec used it before the packers: the signing timestamp brought up to the
    clock, ``msg.pack``, the sequence number advanced."""

    def __init__(self, signer: Signer | None) -> None:
        self.mav = common.MAVLink(None, srcSystem=SYSID, srcComponent=COMPID)
        self.now = signer.now if signer else None
        if signer is not None:
            self.mav.signing.secret_key = signer.key
            self.mav.signing.link_id = signer.link_id
            self.mav.signing.sign_outgoing = True

    def encode(self, msg: Any) -> bytes:
        if self.now is not None:
            self.mav.signing.timestamp = max(self.mav.signing.timestamp, self.now())
        frame: bytes = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) & 0xFF
        return frame


def stepping_clock(rng: np.random.Generator, unix_ns: int) -> Callable[[], int]:
    """A signing clock from ``unix_ns`` that stands still for a while (the encoder's +1 per frame runs ahead of
    it) and jumps; a date before 2015 (a test's ``ManualClock``) reads as signing timestamp 0 until it moves."""
    t = [signing_timestamp(unix_ns)]
    reads = [0]

    def now() -> int:
        reads[0] += 1
        if reads[0] > 5 and rng.random() < 0.2:  # the first frames on the start time
            t[0] += int(rng.integers(1, 1000))
        return t[0]

    return now


def encoders(signed: bool, seed: int, unix_ns: int = 1_800_000_000 * 10**9) -> tuple[FrameEncoder, Reference]:
    clock = stepping_clock(np.random.default_rng(seed), unix_ns)
    # one clock reading per frame for both: each reads its own copy of the same sequence of readings
    readings: list[int] = []
    index = [0, 0]

    def reader(k: int) -> Callable[[], int]:
        def now() -> int:
            while len(readings) <= index[k]:
                readings.append(clock())
            index[k] += 1
            return readings[index[k] - 1]

        return now

    ours = Signer(KEY, 3, reader(0)) if signed else None
    theirs = Signer(KEY, 3, reader(1)) if signed else None
    fallback = common.MAVLink(None, srcSystem=SYSID, srcComponent=COMPID)
    return FrameEncoder(SYSID, COMPID, fallback, ours), Reference(theirs)


def _mismatches(frames: Iterator[tuple[str, bytes, bytes]]) -> list[str]:
    return [f"{name}: {a.hex()} != {b.hex()}" for name, a, b in frames if a != b]


def test_every_message_id_of_both_dialects_has_a_packer() -> None:
    for dialect in DIALECTS:
        missing = [cls.__name__ for cls in message_classes(dialect) if packer_for(cls) is None]
        assert missing == []
    assert len(ardupilotmega.mavlink_map) == 301 and set(common.mavlink_map) < set(ardupilotmega.mavlink_map)
    assert packer_for(common.MAVLink_attitude_message) is packer_for(common.MAVLink_attitude_message)  # cached
    # not covered: another dialect's classes, pymavlink's own pseudo-messages
    for cls in (minimal.MAVLink_heartbeat_message, common.MAVLink_bad_data, common.MAVLink_unknown):
        assert packer_for(cls) is None


@pytest.mark.parametrize("signed", [False, True], ids=["unsigned", "signed"])
@pytest.mark.parametrize("dialect", DIALECTS, ids=lambda d: d.__name__.rsplit(".", 1)[1])
def test_random_messages_frame_byte_for_byte_as_pymavlink(dialect: ModuleType, signed: bool) -> None:
    rng = np.random.default_rng(25)
    ours, reference = encoders(signed, seed=3)
    classes = message_classes(dialect)

    def frames() -> Iterator[tuple[str, bytes, bytes]]:
        for _ in range(8):
            for cls in classes:
                msg = random_message(cls, rng)
                theirs = reference.encode(msg)
                yield cls.__name__, ours.encode(msg), theirs

    assert _mismatches(frames()) == []
    assert ours.fallback_frames == 0
    assert ours.seq == reference.mav.seq == 8 * len(classes) % 256


def test_all_zero_payloads_keep_one_byte_and_trailing_zeros_are_cut() -> None:
    ours, reference = encoders(False, seed=4)
    ack = common.MAVLink_mission_ack_message(0, 0, 0)
    frame = ours.encode(ack)
    assert frame == reference.encode(ack)
    assert frame[1] == 1 and frame[10] == 0 and len(frame) == 10 + 1 + 2  # one zero byte of payload kept
    quaternion = common.MAVLink_attitude_quaternion_message(1, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # extension 0s
    frame = ours.encode(quaternion)
    assert frame == reference.encode(quaternion)
    assert frame[1] == 4 + 4  # time_boot_ms and q1; the zeros after them (the extension too) cut
    given = common.MAVLink_attitude_quaternion_message(1, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, [0.0, 0.0, 0.0, 2.0])
    frame = ours.encode(given)
    assert frame == reference.encode(given)
    assert frame[1] == 48  # the extension's last float is not zero: nothing cut


def test_sequence_and_signing_timestamp_run_on_across_pymavlink_frames() -> None:
    """Messages without a packer (another dialect's class) and fields that do not pack (pymavlink raises, and
    nothing advances) mixed with packed ones, past the sequence number's wrap: the same stream as pymavlink's."""
    rng = np.random.default_rng(7)
    for signed, unix_ns in ((False, 0), (True, 0), (True, 1_800_000_000 * 10**9)):
        ours, reference = encoders(signed, seed=11, unix_ns=unix_ns)
        classes = message_classes(common)
        out: list[tuple[str, bytes, bytes]] = []
        fallbacks = 0
        for k in range(600):
            if k % 7 == 3:
                msg: Any = minimal.MAVLink_heartbeat_message(6, 8, 0, k, 0, 3)
                fallbacks += 1
            else:
                msg = random_message(classes[int(rng.integers(len(classes)))], rng)
            out.append((type(msg).__name__, ours.encode(msg), reference.encode(msg)))
            if k % 50 == 10:
                short = common.MAVLink_attitude_quaternion_message(1, 1.0, 0, 0, 0, 0, 0, 0, [1.0, 2.0])
                with pytest.raises(IndexError):
                    reference.encode(short)
                with pytest.raises(IndexError):  # pymavlink's own error, from its encoder
                    ours.encode(short)
        assert _mismatches(iter(out)) == []
        assert ours.fallback_frames == fallbacks and ours.seq == 600 % 256
        seqs = [frame[4] for _, frame, _ in out]
        assert all((b - a) % 256 == 1 for a, b in itertools.pairwise(seqs))
        if signed:
            stamps = [int.from_bytes(frame[-12:-6], "little") for _, frame, _ in out]
            assert all(b > a for a, b in itertools.pairwise(stamps))


def test_codec_frames_are_numbered_signed_and_verify() -> None:
    clock = iter(range(1_800_000_000 * 10**9, 1_900_000_000 * 10**9, 10**6))
    now: Callable[[], int] = lambda: next(clock)  # noqa: E731
    codec = Codec(1, signing=SigningConfig(KEY, link_id=2), unix_time_ns=now)
    receiver = Codec(9, signing=SigningConfig(KEY), unix_time_ns=now)
    msgs = [codec.mav.heartbeat_encode(2, 12, 129, 4 << 16, 4, 3), codec.mav.statustext_encode(6, b"Takeoff", 1, 0)]
    frames = [codec.encode(m) for m in msgs * 3]
    assert [d.status for f in frames for d in receiver.decode(f)] == [FrameStatus.OK] * 6
    check = common.MAVLink(None)
    check.signing.secret_key = KEY
    parsed = [m for f in frames for m in check.parse_buffer(f) or []]
    assert [m.get_seq() for m in parsed] == list(range(6)) and all(m.get_signed() for m in parsed)
    assert codec.fallback_frames == 0


def test_crc16_both_ways_is_pymavlinks_x25() -> None:
    rng = np.random.default_rng(1)
    for _ in range(300):
        data = rng.bytes(int(rng.integers(0, 300)))
        start = int(rng.integers(0, 0x10000))
        slow = common._x25crc_slow(data)
        assert crc16(data, 0xFFFF) == crc16_stdlib(data, 0xFFFF) == slow.crc
        slow.crc = start
        slow.accumulate(data)
        assert crc16(data, start) == crc16_stdlib(data, start) == slow.crc


@pytest.mark.sim
def test_a_vehicles_traffic_is_all_packed_and_is_pymavlinks_encoding() -> None:
    """A flying vehicle's streams, answers, parameters and texts: no frame through pymavlink's encoder, and
    every frame it sent re-encodes with pymavlink (its own sequence number) to the same bytes."""
    gcs = Gcs()
    rig = Rig(gcs, speed=4.0).start()
    try:
        gcs.connect()
        gcs.keep_raw = True
        assert gcs.command(511, common.MAVLINK_MSG_ID_HIGHRES_IMU, 50_000).result == common.MAV_RESULT_ACCEPTED
        assert gcs.command(511, common.MAVLINK_MSG_ID_SYSTEM_TIME, 100_000).result == common.MAV_RESULT_ACCEPTED
        assert gcs.command(512, common.MAVLINK_MSG_ID_AUTOPILOT_VERSION).result == common.MAV_RESULT_ACCEPTED
        gcs.send(gcs.mav.param_request_read_encode(1, 1, b"MIS_TAKEOFF_ALT", -1))
        gcs.send(gcs.mav.ping_encode(1234, 5, 0, 0))
        gcs.send(gcs.mav.timesync_encode(0, 42))
        gcs.send(gcs.mav.mission_request_list_encode(1, 1, 0))
        assert gcs.command(400, 1).result == common.MAV_RESULT_ACCEPTED
        gcs.command(22, 0, 0, 0, float("nan"), float("nan"), float("nan"), float("nan"))
        gcs.collect(2.5)
    finally:
        rig.stop()
        gcs.close()
    parser = common.MAVLink(None)
    sent = [m for d in gcs.raw for m in parser.parse_buffer(d) or [] if m.get_srcSystem() == 1]
    kinds = {m.get_type() for m in sent}
    assert kinds >= {
        "HEARTBEAT",
        "ATTITUDE",
        "ATTITUDE_QUATERNION",
        "GLOBAL_POSITION_INT",
        "SYS_STATUS",
        "BATTERY_STATUS",
        "HIGHRES_IMU",
        "SYSTEM_TIME",
        "AUTOPILOT_VERSION",
        "PARAM_VALUE",
        "PING",
        "TIMESYNC",
        "MISSION_COUNT",
        "COMMAND_ACK",
        "STATUSTEXT",
    }, kinds
    assert rig.server.codec.fallback_frames == 0
    mismatched = []
    for m in sent:
        frame = bytes(m.get_msgbuf())
        ref = common.MAVLink(None, srcSystem=1, srcComponent=m.get_srcComponent())  # (the camera's heartbeat: 100)
        ref.seq = m.get_seq()
        if m.pack(ref) != frame:
            mismatched.append(m.get_type())
    assert mismatched == [] and len(sent) > 100
