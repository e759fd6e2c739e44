"""MAVLink 2 signing (refusals counted, telemetry signed) and bad-input robustness (seeded fuzzer)."""

from __future__ import annotations

import functools
import hashlib

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.mavlink import SigningConfig
from harness.autopilot.mavlink.codec import Codec, FrameStatus
from harness.core.clock import real_time_ns
from tests.autopilot.mavlink.conftest import Gcs, Rig

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


def _fuzz_one(rng: np.random.Generator, valid: list[bytes]) -> bytes:
    r = rng.random()
    if r < 0.3:
        return rng.bytes(int(rng.integers(1, 300)))
    f = bytearray(valid[int(rng.integers(len(valid)))])
    if r < 0.8:
        for _ in range(int(rng.integers(1, 4))):
            f[int(rng.integers(len(f)))] ^= int(rng.integers(1, 256))
        return bytes(f)
    if r < 0.9:
        return bytes(f[: int(rng.integers(1, len(f)))])
    f[7:10] = rng.bytes(3)  # a valid header with a random message id
    return bytes(f)


def _fuzz_datagrams(rng: np.random.Generator, valid: list[bytes], n: int) -> list[bytes]:
    """``n`` garbage datagrams. A mutation that happens to yield a valid frame (CRC collision, about 1 in
    65,536) is a real command that any unsigned link must obey, so it is replaced: only invalid input here."""
    check = Codec(250)
    out: list[bytes] = []
    while len(out) < n:
        d = _fuzz_one(rng, valid)
        if all(x.status is not FrameStatus.OK for x in check.decode(d)):
            out.append(d)
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
        assert rig.server.alive
        # still fully responsive, and the vehicle is still sane
        ack = gcs.command(512, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        assert ack.result == M.MAV_RESULT_ACCEPTED
        assert gcs.recv("HEARTBEAT", 2.0)
    finally:
        rig.stop()


def _hover_fuzz(gcs: Gcs, n: int) -> None:
    rig = Rig(gcs, seed=5, speed=2.0).start()
    try:
        gcs.connect()
        assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0).result == M.MAV_RESULT_ACCEPTED
        assert (
            gcs.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, float("nan"), float("nan"), float("nan"), float("nan")).result
            == 0
        )
        gcs.recv("HEARTBEAT", 20.0, lambda m: (m.custom_mode >> 24) == 3)  # AUTO.LOITER after takeoff
        gcs.collect(2.0)  # settle
        hold = tuple(rig.sim.pos)
        mav = gcs.mav
        valid = [
            mav.command_long_encode(1, 1, 21, 0, 0, 0, 0, 0, 0, 0, 0).pack(mav),  # LAND, if it ever got through
            mav.command_int_encode(1, 1, 6, 192, 0, 0, -1, 1, 0, 0, 473977420, 85455940, 50.0).pack(mav),
            mav.set_position_target_local_ned_encode(0, 1, 1, 1, 0, 9, 9, -9, 0, 0, 0, 0, 0, 0, 0, 0).pack(mav),
            mav.param_set_encode(1, 1, b"MPC_XY_P", 0.1, 9).pack(mav),
        ]
        rng = np.random.default_rng(2024)
        worst = 0.0
        sent = 0
        while sent < n:
            for d in _fuzz_datagrams(rng, valid, 500):
                gcs.send_raw(d)
            sent += 500
            gcs.collect(0.01)
            worst = max(worst, max(abs(a - b) for a, b in zip(rig.sim.pos, hold, strict=True)))
        gcs.collect(0.5)
        worst = max(worst, max(abs(a - b) for a, b in zip(rig.sim.pos, hold, strict=True)))
        c = rig.server.counters()
        assert worst <= 0.5, f"drifted {worst:.2f} m from the hover point under fuzzing: {c}"
        assert c.malformed + c.unknown_msg >= 0.7 * n
        assert c.handler_errors == 0 or rig.server.alive
        assert rig.ap.telemetry.state().mode.name == "HOLD" and rig.ap.telemetry.state().armed
        assert gcs.command(512, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION).result == M.MAV_RESULT_ACCEPTED
    finally:
        rig.stop()


def test_fuzz_while_hovering_keeps_position(gcs: Gcs) -> None:
    _hover_fuzz(gcs, 3000)


@pytest.mark.soak
def test_fuzz_100k_while_hovering(gcs: Gcs) -> None:
    _hover_fuzz(gcs, 100_000)


_NASTY = (float("nan"), float("inf"), -float("inf"), 1e38, -1e38, 0.0, -1.0, 1.0, 21196.0, 3.0e9)
_CMDS = (16, 20, 21, 22, 34, 176, 178, 179, 192, 300, 400, 410, 420, 511, 512, 520, 246, 31000, 0, 65535)
_PX4_SITL_CMDS = (241, 246, 1000, 1001, 195, 197)
"""PX4 SITL's own services' commands (calibration, reboot, gimbal), fuzzed after the others."""


def _nasty(rng: np.random.Generator) -> float:
    return float(_NASTY[int(rng.integers(len(_NASTY)))]) if rng.random() < 0.5 else float(rng.normal(0, 1e3))


def _is_command(command: int, m: object) -> bool:
    return bool(m.command == command)  # type: ignore[attr-defined]


def test_valid_frames_with_hostile_values_are_all_answered(gcs: Gcs, idle_rig: Rig) -> None:
    """Well-formed commands with NaN, infinities and absurd values: every one gets exactly one ACK."""
    rng = np.random.default_rng(99)
    mav = gcs.mav
    for i in range(200):
        cmd = int(_CMDS[int(rng.integers(len(_CMDS)))])
        p = [_nasty(rng) for _ in range(7)]
        if i % 2:
            x, y = (int(rng.integers(-(2**31), 2**31)) for _ in range(2))
            frame = int(rng.choice([0, 3, 5, 6, 1, 99]))
            gcs.send(mav.command_int_encode(1, 1, frame, cmd, 0, 0, p[0], p[1], p[2], p[3], x, y, p[6]))
        else:
            gcs.send(mav.command_long_encode(1, 1, cmd, 0, *p))
        ack = gcs.recv("COMMAND_ACK", 2.0, functools.partial(_is_command, cmd))
        assert ack.result in (0, 1, 2, 3, 4), ack
        if cmd in (31000, 0, 65535):
            assert ack.result == M.MAV_RESULT_UNSUPPORTED
    for _ in range(60):  # the same for PX4 SITL's services (a reboot may be among them: the rig is idle)
        cmd = int(_PX4_SITL_CMDS[int(rng.integers(len(_PX4_SITL_CMDS)))])
        p = [_nasty(rng) for _ in range(7)]
        gcs.send(mav.command_long_encode(1, 1, cmd, 0, *p))
        ack = gcs.recv("COMMAND_ACK", 2.0, functools.partial(_is_command, cmd))
        assert ack.result in (0, 1, 2, 3, 4), ack
    for _ in range(100):  # parameters, mission items and setpoints with hostile values
        gcs.send(mav.param_set_encode(1, 1, b"MPC_XY_VEL_MAX", _nasty(rng), int(rng.integers(0, 12))))
        gcs.send(
            mav.mission_item_int_encode(
                1,
                1,
                int(rng.integers(0, 5)),
                int(rng.integers(0, 20)),
                int(rng.integers(0, 65536)),
                0,
                1,
                *(_nasty(rng) for _ in range(4)),
                5,
                6,
                _nasty(rng),
                int(rng.integers(0, 4)),
            )
        )
        gcs.send(
            mav.set_position_target_local_ned_encode(
                0, 1, 1, int(rng.integers(0, 13)), int(rng.integers(0, 4096)), *(_nasty(rng) for _ in range(11))
            )
        )
        gcs.send(
            mav.set_attitude_target_encode(
                0, 1, 1, int(rng.integers(0, 256)), [_nasty(rng) for _ in range(4)], *(_nasty(rng) for _ in range(4))
            )
        )
        gcs.collect(0.002)
    gcs.collect(0.3)
    c = idle_rig.server.counters()
    assert c.handler_errors == 0
    assert sum(c.commands.values()) == 260  # 200 + 60 of PX4 SITL's services
    assert 0.0 <= idle_rig.ap.params["MPC_XY_VEL_MAX"] <= 20.0  # only in-range values were taken
    assert gcs.command(512, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION).result == M.MAV_RESULT_ACCEPTED
