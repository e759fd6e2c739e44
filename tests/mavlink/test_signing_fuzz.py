"""MAVLink 2 signing (refusals counted, telemetry signed) and bad-input robustness (seeded fuzzer)."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.mavlink import SigningConfig
from harness.autopilot.mavlink.codec import Codec, FrameStatus
from harness.simclock.clock import real_time_ns
from tests.mavlink.conftest import Gcs, Rig

M = mavlink2
KEY = hashlib.sha256(b"uav-harness test key").digest()


def test_signing_refuses_unsigned_and_wrongly_signed_commands(gcs: Gcs) -> None:
    rig = Rig(gcs, signing=SigningConfig(KEY)).start(stepping=False)
    try:
        hb = gcs.recv("HEARTBEAT")
        # telemetry is signed with our key: a parser holding the key accepts it, the signature is valid
        assert hb.get_signed() is False  # our plain parser does not check...
        check = mavlink2.MAVLink(None)
        check.signing.secret_key = KEY
        gcs.keep_raw = True
        gcs.collect(0.3)
        signed = [m for d in gcs.raw for m in (check.parse_buffer(d) or [])]
        assert signed and all(m.get_signed() for m in signed)
        gcs.keep_raw = False
        # unsigned command: refused silently, counted
        gcs.send(gcs.mav.command_long_encode(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
        with pytest.raises(AssertionError):
            gcs.recv("COMMAND_ACK", 0.5)
        # wrongly signed command
        liar = Gcs(key=hashlib.sha256(b"wrong").digest())
        liar.server = gcs.server
        liar.send(liar.mav.command_long_encode(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
        liar.close()
        # correctly signed command: accepted (and a replay of its exact bytes is refused)
        good = Gcs(key=KEY)
        good.server = gcs.server
        good_addr = good.sock.getsockname()[:2]
        frame = good.mav.command_long_encode(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(
            good.mav
        )
        good.send_raw(frame)
        ack = good.recv("COMMAND_ACK", 2.0)
        assert ack.result == M.MAV_RESULT_ACCEPTED
        good.send_raw(frame)
        good.collect(0.3)
        good.close()
        c = rig.server.counters()
        assert c.refused_unsigned == 1
        assert c.refused_bad_signature == 2  # wrong key + replay
        assert c.commands == {"ACCEPTED": 1}
        assert rig.server.links[0].peers() == [good_addr]  # unsigned and wrongly signed senders are no peers
    finally:
        rig.stop()


def test_codec_classifies_frames() -> None:
    now = real_time_ns
    server = Codec(1, signing=SigningConfig(KEY), unix_time_ns=now)
    plain = Codec(9)
    signer = Codec(9, signing=SigningConfig(KEY, link_id=3), unix_time_ns=now)
    stranger = Codec(9, signing=SigningConfig.from_passphrase("other"), unix_time_ns=now)
    hb = plain.mav.heartbeat_encode(6, 8, 0, 0, 0, 3)
    assert [d.status for d in server.decode(plain.encode(hb))] == [FrameStatus.UNSIGNED]
    assert [d.status for d in server.decode(stranger.encode(hb))] == [FrameStatus.BAD_SIGNATURE]
    two = signer.encode(hb) + signer.encode(hb)
    assert [d.status for d in server.decode(two)] == [FrameStatus.OK, FrameStatus.OK]
    frame = bytearray(plain.encode(hb))
    frame[11] ^= 0xFF  # payload byte: CRC mismatch
    assert [d.status for d in Codec(1).decode(bytes(frame))] == [FrameStatus.MALFORMED]
    assert [d.status for d in Codec(1).decode(plain.encode(hb)[:-3])] == [FrameStatus.MALFORMED]
    assert FrameStatus.MALFORMED in {d.status for d in Codec(1).decode(b"\x00\x01garbage")}


def _fuzz_datagrams(rng: np.random.Generator, valid: list[bytes], n: int) -> list[bytes]:
    out = []
    for _ in range(n):
        r = rng.random()
        if r < 0.3:
            out.append(rng.bytes(int(rng.integers(1, 300))))
        elif r < 0.8:
            f = bytearray(valid[int(rng.integers(len(valid)))])
            for _ in range(int(rng.integers(1, 4))):
                f[int(rng.integers(len(f)))] = int(rng.integers(256))
            out.append(bytes(f))
        elif r < 0.9:
            f = valid[int(rng.integers(len(valid)))]
            out.append(f[: int(rng.integers(1, len(f)))])
        else:  # a valid header with a random payload and message id
            f = bytearray(valid[int(rng.integers(len(valid)))])
            f[7:10] = rng.bytes(3)
            out.append(bytes(f))
    return out


def test_fuzzed_frames_never_crash_and_are_counted(gcs: Gcs) -> None:
    rig = Rig(gcs, seed=3).start(stepping=False)
    try:
        gcs.connect()
        mav = gcs.mav
        valid = [
            mav.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav),
            mav.command_int_encode(1, 1, 6, 192, 0, 0, -1, 1, 0, 0, 473977420, 85455940, 20.0).pack(mav),
            mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 3.0, 9).pack(mav),
            mav.mission_count_encode(1, 1, 3, 0).pack(mav),
            mav.mission_item_int_encode(1, 1, 0, 6, 16, 0, 1, 0, 0, 0, 0, 1, 2, 3.0, 0).pack(mav),
            mav.set_position_target_local_ned_encode(0, 1, 1, 1, 0, 1, 2, -3, 0, 0, 0, 0, 0, 0, 0, 0).pack(mav),
            mav.set_attitude_target_encode(0, 1, 1, 0, [1, 0, 0, 0], 0, 0, 0, 0.5).pack(mav),
            mav.param_request_read_encode(1, 1, b"X", 7).pack(mav),
            mav.mission_request_list_encode(1, 1, 2).pack(mav),
        ]
        data = _fuzz_datagrams(np.random.default_rng(12345), valid, 5000)
        before = rig.server.counters()
        for i, d in enumerate(data):
            gcs.send_raw(d)
            if i % 200 == 199:
                gcs.collect(0.005)  # pace (loopback buffers) and drain replies
        gcs.collect(0.5)
        c = rig.server.counters()
        received = c.datagrams_rx - before.datagrams_rx
        assert received >= 0.95 * len(data)
        bad = (c.malformed - before.malformed) + (c.unknown_msg - before.unknown_msg)
        assert bad >= 0.7 * received
        assert rig.server._thread is not None and rig.server._thread.is_alive()
        # still fully responsive, and the vehicle is still sane
        ack = gcs.command(512, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        assert ack.result == M.MAV_RESULT_ACCEPTED
        assert gcs.recv("HEARTBEAT", 2.0)
    finally:
        rig.stop()
