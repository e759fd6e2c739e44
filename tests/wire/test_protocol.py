"""The codec: every message round-trips; garbage is refused with ProtocolError, never anything else."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from harness.wire import protocol as p

i64 = st.integers(min_value=0, max_value=2**62)
veh = st.integers(min_value=-1, max_value=10_000)
flt = st.floats(allow_nan=False, allow_infinity=False, width=64)
vec3 = st.tuples(flt, flt, flt)
packet = st.builds(p.Packet, i64, veh, veh, st.integers(0, 65535), i64, st.binary(max_size=64))

messages = st.one_of(
    st.builds(p.Challenge, st.integers(0, 10), st.binary(min_size=16, max_size=16)),
    st.builds(
        p.Hello,
        st.integers(0, 10),
        st.sampled_from(list(p.PeerKind)),
        st.text(max_size=20),
        veh,
        st.lists(veh, max_size=5).map(tuple),
        st.binary(max_size=32),
    ),
    st.builds(p.Welcome, i64, i64, i64),
    st.builds(p.BeginTickAC, i64, i64, veh, st.integers(1, 100), vec3, st.binary(max_size=300)),
    st.builds(p.EndTickAC, i64, veh, st.lists(flt, min_size=4, max_size=4).map(tuple)),
    st.builds(
        p.EndTickAC,
        i64,
        veh,
        st.lists(flt, min_size=4, max_size=4).map(tuple),
        st.integers(0, 2**24),
        st.integers(0, 6).map(lambda k: bytes(range(p.TICK_BYTES)) * k),
    ),
    st.builds(p.BeginTick0, i64, i64),
    st.builds(p.EndTick0, i64),
    st.builds(p.Enqueue, packet),
    st.builds(
        p.BeginTick1,
        i64,
        i64,
        i64,
        st.lists(st.builds(p.VehiclePosition, veh, vec3), max_size=4).map(tuple),
        st.lists(packet, max_size=4).map(tuple),
    ),
    st.builds(p.Deliver, i64, packet, flt),
    st.builds(p.EndTick1, i64),
    st.builds(p.Bye, st.text(max_size=20), st.integers(-255, 255)),
    st.builds(p.Error, st.sampled_from(list(p.ErrorCode)), st.text(max_size=40), st.booleans()),
)


@given(st.lists(messages, min_size=1, max_size=8), st.integers(1, 64))
@settings(max_examples=300, deadline=None)
def test_round_trip_in_any_chunking(msgs: list[p.Message], chunk: int) -> None:
    data = p.encode_many(msgs)
    dec = p.FrameDecoder()
    out: list[p.Message] = []
    for i in range(0, len(data), chunk):
        out += dec.feed(data[i : i + chunk])
    assert out == msgs and dec.pending == 0


@given(st.binary(min_size=1, max_size=200))
@settings(max_examples=500, deadline=None)
def test_garbage_raises_protocol_error_only(data: bytes) -> None:
    dec = p.FrameDecoder(max_frame=1024)
    try:
        for msg in dec.feed(data):
            assert isinstance(msg, p._Msg)
    except p.ProtocolError:
        pass


def test_oversized_length_prefix_is_refused_without_allocating() -> None:
    with pytest.raises(p.ProtocolError, match="exceeds the limit"):
        p.FrameDecoder().feed(b"\xff\xff\xff\xff" + b"x" * 10)


def test_wrong_field_type_is_malformed() -> None:
    import msgspec

    body = msgspec.msgpack.encode(["ET0", "not-an-int"])
    with pytest.raises(p.ProtocolError, match="malformed"):
        p.FrameDecoder().feed(len(body).to_bytes(4, "big") + body)


def test_auth_token_binds_nonce_and_name() -> None:
    t = p.auth_token(b"k", b"n" * 16, "a")
    assert p.check_auth(b"k", b"n" * 16, "a", t)
    assert not p.check_auth(b"k", b"m" * 16, "a", t)
    assert not p.check_auth(b"k", b"n" * 16, "b", t)
    assert not p.check_auth(b"x", b"n" * 16, "a", t)


def test_tick_records_keep_every_bit_and_a_torn_one_is_malformed() -> None:
    """END-TICK-AC ``ticks``: a worker's ground truth must reach the root bit for bit (the recording of a
    run with workers is compared byte for byte); a length that is not whole records is a malformed frame."""
    truth = p.TruthReport(
        (0.1, -1 / 3, -2.5e-17), (1e-300, -0.0, 3.0), (0.9, 0.1, -0.2, 0.3), 47.1, 8.5, 488.0, True, True
    )
    records = p.pack_tick(truth, (0.0, 0.5, 1.0, 1 / 7), 0x12345) + p.pack_tick(
        truth._replace(pos_ned_m=(4.0, 5.0, -6.0), on_ground=False), (1.0, 1.0, 1.0, 1.0), 1
    )
    eta = p.EndTickAC(8, 3, (1.0, 1.0, 1.0, 1.0), 1, records)
    back = p.decode_body(p.encode(eta)[4:])
    assert back == eta
    first, second = p.unpack_ticks(back.ticks)  # type: ignore[union-attr]
    assert first == p.TickReport(truth, (0.0, 0.5, 1.0, 1 / 7), 0x12345)
    assert second.truth.pos_ned_m == (4.0, 5.0, -6.0) and not second.truth.on_ground and second.truth.crashed
    assert p.last_position(records) == (4.0, 5.0, -6.0)
    torn = p.encode(eta)[:4] + p.encode(eta)[4:]  # the same frame, then one with a record cut short
    assert p.decode_body(torn[4:]) == eta
    import msgspec

    body = msgspec.msgpack.encode(["ETA", 8, 3, [1.0, 1.0, 1.0, 1.0], 1, records[:-1]])
    with pytest.raises(p.ProtocolError, match=f"not a multiple of {p.TICK_BYTES}"):
        p.decode_body(body)


@given(
    st.booleans(),
    st.integers(0, 4),
    st.integers(0, 255),
    st.integers(0, 255),
    st.floats(-90.0, 30.0),
    st.floats(-180.0, 180.0),
)
def test_status_carries_a_gimbal_to_a_thousandth_of_a_degree_and_nothing_without_one(
    armed: bool, landed: int, main: int, sub: int, pitch: float, yaw: float
) -> None:
    """END-TICK-AC ``status`` with a gimbal: the mode fields read as before, the attitude to 0.0005 deg, through
    a worker's tick record too; without a gimbal the status is the old one, and says none."""
    bare = p.pack_status(armed, landed, main, sub)
    assert bare == p.pack_status(armed, landed, main, sub, None) < p.STATUS_GIMBAL
    assert p.unpack_gimbal(bare) is None
    status = p.pack_status(armed, landed, main, sub, (pitch, yaw))
    assert p.unpack_status(status) == p.unpack_status(bare) == (armed, landed, main, sub)
    got = p.unpack_gimbal(status)
    assert got is not None and abs(got[0] - pitch) <= 0.0005 and abs(got[1] - yaw) <= 0.0005
    truth = p.TruthReport((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), 47.0, 8.0, 400.0, True, False)
    (report,) = p.unpack_ticks(p.pack_tick(truth, (0.0, 0.0, 0.0, 0.0), status))
    assert report.status == status
    assert p.decode_body(p.encode(p.EndTickAC(1, 0, (0.0,) * 4, status))[4:]) == p.EndTickAC(1, 0, (0.0,) * 4, status)


def test_a_commanded_gimbal_angle_reads_back_exactly() -> None:
    assert p.unpack_gimbal(p.pack_status(True, 2, 4, 3, (-60.0, 30.0))) == (-60.0, 30.0)
    assert p.unpack_gimbal(p.pack_status(False, 1, 0, 0, (-90.0, -180.0))) == (-90.0, -180.0)
    assert p.unpack_gimbal(p.pack_status(False, 1, 0, 0, (90.0, 180.0))) == (90.0, 180.0)
