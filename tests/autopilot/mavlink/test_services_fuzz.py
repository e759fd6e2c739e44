"""A property test of the MAVLink server's services over a real UDP socket (issue 36, item 7): Hypothesis draws
messages of every service (commands, parameters, missions, MAVFTP, the shell, setpoints, logs, ...) with any
value of any field (NaN and infinities, frames and parameter types of 0..255, target ids), at any payload
length from 0 to 255 bytes (CRC made right, so the frame reaches the services). Whatever comes, the server
never raises (no handler error), its thread lives, every datagram it sends parses as MAVLink, what must be
answered is (a COMMAND_ACK for each command, a MAVFTP reply for each request, a PARAM_VALUE for a read of an
existing index), and a PARAM_SET leaves its parameter unchanged or set to the value sent read in the
parameter's own type (a UINT8 write to a REAL32 parameter set the float's low byte: issue 36, item 3). Small enough for CI: ``FUZZ_EXAMPLES`` examples, a few seconds."""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as M

from harness.autopilot.mavlink.parameters import decode_value
from harness.autopilot.params import PARAM_DEFS, ParamDef, ParamType
from tests.autopilot.mavlink.conftest import Gcs
from tests.autopilot.mavlink.test_px4_sitl_services import _Vehicle

FUZZ_EXAMPLES = int(os.environ.get("HARNESS_FUZZ_EXAMPLES", "120"))
MESSAGES = (
    "COMMAND_LONG",
    "COMMAND_INT",
    "PARAM_SET",
    "PARAM_REQUEST_READ",
    "PARAM_REQUEST_LIST",
    "MISSION_COUNT",
    "MISSION_ITEM_INT",
    "MISSION_ITEM",
    "MISSION_REQUEST_INT",
    "MISSION_REQUEST_LIST",
    "MISSION_CLEAR_ALL",
    "MISSION_SET_CURRENT",
    "MISSION_ACK",
    "FILE_TRANSFER_PROTOCOL",
    "SERIAL_CONTROL",
    "SET_POSITION_TARGET_LOCAL_NED",
    "SET_POSITION_TARGET_GLOBAL_INT",
    "SET_ATTITUDE_TARGET",
    "SET_MODE",
    "PING",
    "TIMESYNC",
    "MANUAL_CONTROL",
    "RC_CHANNELS_OVERRIDE",
    "LOG_REQUEST_LIST",
    "LOG_REQUEST_DATA",
    "GIMBAL_MANAGER_SET_ATTITUDE",
    "HEARTBEAT",
)
_WEIGHTED = MESSAGES + ("PARAM_SET", "COMMAND_LONG", "MISSION_ITEM_INT", "FILE_TRANSFER_PROTOCOL", "SERIAL_CONTROL") * 3
"""The services of issue 36 drawn more often."""
_COMMANDS = (16, 20, 21, 22, 176, 178, 179, 192, 241, 246, 300, 400, 410, 511, 512, 520, 1000, 1001, 224, 2000)
_INTS = {
    "uint8_t": (0, 255),
    "int8_t": (-128, 127),
    "uint16_t": (0, 65535),
    "int16_t": (-32768, 32767),
    "uint32_t": (0, 2**32 - 1),
    "int32_t": (-(2**31), 2**31 - 1),
    "uint64_t": (0, 2**64 - 1),
    "int64_t": (-(2**63), 2**63 - 1),
}
_FLOATS = st.floats(width=32, allow_nan=True, allow_infinity=True)
_PATHS = st.sampled_from(
    [b"/", b"/etc", b"/etc/f.txt", b"/parameters.json", b"/log", b"/../../etc/passwd", b"@SYS", b"/etc/d/"]
) | st.binary(max_size=40)
_FTP_PAYLOAD = st.builds(
    lambda seq, session, op, size, offset, path: list(
        (struct.pack("<HBBBBBBI", seq, session, op, size, 0, 0, 0, offset) + path + b"\0").ljust(251, b"\0")[:251]
    ),
    st.integers(0, 65535),
    st.integers(0, 5),
    st.integers(0, 17) | st.sampled_from([128, 129, 255]),
    st.integers(0, 255),
    st.sampled_from([0, 1, 239, 1 << 20, 2**32 - 1]),
    _PATHS,
)
_SHELL = st.sampled_from(
    [b"help\n", b"ver all\n", b"param show MIS*\n", b"param set MIS_TAKEOFF_ALT 3\n", b"listener nope\n", b"\n"]
) | st.binary(max_size=70)
_OVERRIDES: dict[str, st.SearchStrategy[Any]] = {
    "target_system": st.sampled_from([0, 1, 1, 1, 2]),
    "target_component": st.sampled_from([0, 1, 1, 190]),
    "command": st.sampled_from(_COMMANDS) | st.integers(0, 65535),
    "param_type": st.integers(0, 12) | st.integers(0, 255),
    "param_index": st.integers(-1, len(PARAM_DEFS) + 2),
    "param_id": st.sampled_from([b"MIS_TAKEOFF_ALT", b"SYS_HITL", b"MPC_XY_VEL_MAX", b"NOPE"]) | st.binary(max_size=16),
    "mission_type": st.sampled_from([0, 1, 2, 255]) | st.integers(0, 255),
    "count": st.integers(0, 3) | st.integers(0, 65535),
}


def _field(msg_cls: Any, name: str, ftype: str, length: int) -> st.SearchStrategy[Any]:
    if msg_cls is M.MAVLink_file_transfer_protocol_message and name == "payload":
        return _FTP_PAYLOAD
    if msg_cls is M.MAVLink_serial_control_message and name == "data":
        return _SHELL.map(lambda b: list(b.ljust(70, b"\0")))
    if name in _OVERRIDES and ftype in _INTS:  # kept within the field's type (SERIAL_CONTROL's count is a uint8)
        lo, hi = _INTS[ftype]
        return _OVERRIDES[name].map(lambda v: min(max(v, lo), hi))
    if name in _OVERRIDES:
        return _OVERRIDES[name]
    if ftype == "char":
        return st.binary(max_size=length or 1)
    one = _FLOATS if ftype in ("float", "double") else st.integers(*_INTS[ftype])
    return st.lists(one, min_size=length, max_size=length) if length else one


@st.composite
def frames(draw: st.DrawFn, mav: M.MAVLink) -> tuple[bytes, Any]:
    """One frame of a drawn message and payload length, with a right CRC; and the message the server decodes
    from it (None when it is not a valid frame for the parser)."""
    name = draw(st.sampled_from(_WEIGHTED))
    cls = getattr(M, f"MAVLink_{name.lower()}_message")
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))  # in wire order
    values = [draw(_field(cls, n, t, lengths[n])) for n, t in zip(cls.fieldnames, cls.fieldtypes, strict=True)]
    frame = bytearray(cls(*values).pack(mav))
    length = draw(st.none() | st.integers(0, 255))
    if length is not None:
        payload = (bytes(frame[10:-2]) + bytes(255))[:length]
        header = bytes([frame[0], length]) + bytes(frame[2:10])
        crc = M.x25crc(header[1:] + payload)
        crc.accumulate(bytes([cls.crc_extra]))
        frame = bytearray(header + payload + struct.pack("<H", crc.crc))
    parser = M.MAVLink(None)
    parser.robust_parsing = True
    try:
        decoded = [m for m in parser.parse_buffer(bytes(frame)) or [] if not isinstance(m, M.MAVLink_bad_data)]
    except Exception:  # the server's codec takes these as malformed
        decoded = []
    return bytes(frame), decoded[0] if decoded else None


def _expected(m: Any) -> tuple[str, Any] | None:
    """What the server must answer to ``m`` (message type, and a condition on it), or None."""
    if m is None or getattr(m, "target_system", 1) not in (0, 1) or getattr(m, "target_component", 1) not in (0, 1):
        return None
    kind = m.get_type()
    if kind in ("COMMAND_LONG", "COMMAND_INT"):
        return "COMMAND_ACK", lambda a: a.command == m.command
    if kind == "FILE_TRANSFER_PROTOCOL" and m.target_network == 0:
        op = bytes(m.payload)[3]
        if op < 128 and op not in (14, 15):  # a large file's CRC32 and a burst may take several ticks
            return "FILE_TRANSFER_PROTOCOL", lambda a: bytes(a.payload)[5] == op
    if kind == "PARAM_REQUEST_READ" and 0 <= m.param_index < len(PARAM_DEFS):
        return "PARAM_VALUE", lambda a: a.param_index == m.param_index
    return None


def _param_set_to_us(m: Any) -> ParamDef | None:
    """The parameter a decoded PARAM_SET addressed to the vehicle sets (None for any other message)."""
    if m is None or m.get_type() != "PARAM_SET" or m.target_system not in (0, 1) or m.target_component not in (0, 1):
        return None
    return next((d for d in PARAM_DEFS if d.name == m.param_id), None)


def _read(gcs: Gcs, param: ParamDef) -> float:
    """The parameter's value as the vehicle reports it now (after everything sent before: one socket, in order)."""
    gcs.send(gcs.mav.param_request_read_encode(1, 1, param.name.encode(), -1))
    m = gcs.recv("PARAM_VALUE", 3.0, lambda v: v.param_id == param.name)
    own = M.MAV_PARAM_TYPE_INT32 if param.type == ParamType.INT32 else M.MAV_PARAM_TYPE_REAL32
    return decode_value(m.param_value, own)


@pytest.fixture(scope="module")
def fuzzed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Gcs, _Vehicle]]:
    gcs = Gcs()
    vehicle = _Vehicle(gcs, tmp_path_factory.mktemp("fuzz"))
    vehicle.step_s(12.0)
    gcs.connect()
    yield gcs, vehicle
    vehicle.attached.close()
    gcs.close()


@settings(
    max_examples=FUZZ_EXAMPLES,
    deadline=None,
    derandomize=True,  # the same examples on every run (seeded, as every test here): CI results repeat
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(data=st.data())
def test_the_server_never_raises_and_answers_well_formed_whatever_its_services_get(
    fuzzed: tuple[Gcs, _Vehicle], data: st.DataObject
) -> None:
    gcs, vehicle = fuzzed
    server = vehicle.attached.server
    frame, decoded = data.draw(frames(gcs.mav))
    param = _param_set_to_us(decoded)
    before = _read(gcs, param) if param is not None else None
    gcs.keep_raw, gcs.raw = True, []
    gcs.send_raw(frame)
    expect = _expected(decoded)
    if expect is not None:
        kind, cond = expect
        gcs.recv(kind, 3.0, cond)
    else:
        gcs.collect(0.01)
    gcs.keep_raw = False
    strict = M.MAVLink(None)
    for datagram in gcs.raw:  # every frame the vehicle sent parses, CRC and all
        assert all(not isinstance(m, M.MAVLink_bad_data) for m in strict.parse_buffer(datagram) or [])
    if param is not None:  # a PARAM_SET leaves the value as it was, or sets what was sent read in its own type
        own = M.MAV_PARAM_TYPE_INT32 if param.type == ParamType.INT32 else M.MAV_PARAM_TYPE_REAL32
        after = _read(gcs, param)
        sent = decode_value(decoded.param_value, own)
        assert after == before or (decoded.param_type == own and after == pytest.approx(sent, rel=1e-6)), (
            f"PARAM_SET {param.name} of type {decoded.param_type} ({decoded.param_value!r}): {before} -> {after}"
        )
    counters = server.counters()
    assert counters.handler_errors == 0, f"a service raised on {decoded or frame.hex()}"
    assert server.alive
