"""The pure pieces of the MAVLink interface, tested directly: value encoding, STATUSTEXT chunking, setpoint
conversion, stream scheduling on two clocks, heartbeat schedule, peer expiry, retransmission handling."""

from __future__ import annotations

import math
import struct

from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.action import Actions
from harness.autopilot.api import CommandResult, FlightMode, OffboardFrame, Severity, VehicleState
from harness.autopilot.autopilot import Autopilot
from harness.autopilot.mavlink.codec import Codec
from harness.autopilot.mavlink.commands import CommandIn, CommandService
from harness.autopilot.mavlink.heartbeat import HeartbeatSchedule
from harness.autopilot.mavlink.messages import statustext, text_of
from harness.autopilot.mavlink.offboard import attitude_target, position_target
from harness.autopilot.mavlink.parameters import decode_value, encode_value
from harness.autopilot.mavlink.telemetry import StreamScheduler
from harness.autopilot.mavlink.transport import LinkConfig, UdpLink

M = mavlink2
MAV = Codec(1).mav


def _not_signalling_nan(v: int) -> bool:
    """Python floats cannot carry a float32 signalling-NaN bit pattern (the conversion quiets it): INT32
    values in [-8388607, -4194305] and [2139095041, 2143289343] cannot travel bytewise through pymavlink.
    No parameter has such a range (see docs/mavlink.md)."""
    bits = v & 0xFFFFFFFF
    return not ((bits & 0x7F800000) == 0x7F800000 and bits & 0x007FFFFF and not bits & 0x00400000)


@given(st.integers(min_value=-(2**31), max_value=2**31 - 1).filter(_not_signalling_nan))
def test_int32_parameters_survive_bytewise_encoding_and_the_wire(v: int) -> None:
    f = encode_value(v, M.MAV_PARAM_TYPE_INT32)
    assert struct.pack("<f", f) == struct.pack("<i", v)
    # through a real PARAM_VALUE frame and back (NaN bit patterns included)
    sender, receiver = Codec(1), Codec(2)
    frame = sender.encode(sender.mav.param_value_encode(b"X", f, M.MAV_PARAM_TYPE_INT32, 1, 0))
    (d,) = receiver.decode(frame)
    assert d.message is not None
    assert decode_value(d.message.param_value, M.MAV_PARAM_TYPE_INT32) == v


@given(st.floats(width=32, allow_nan=False))
def test_float_parameters_are_plain(v: float) -> None:
    assert decode_value(encode_value(v, M.MAV_PARAM_TYPE_REAL32), M.MAV_PARAM_TYPE_REAL32) == v


def test_every_int_parameter_range_travels_bytewise() -> None:
    from harness.autopilot.params import PARAM_DEFS, ParamType

    for d in PARAM_DEFS:
        if d.type == ParamType.INT32:
            assert _not_signalling_nan(int(d.min)) and _not_signalling_nan(int(d.max)), d.name
            assert _not_signalling_nan(int(d.default)), d.name
            # longitude x 1e7 from PX4's default, -73.76 deg: -0.84..-0.42 deg cannot travel bytewise
            if d.name == "SIH_LOC_LON0":
                continue
            assert int(d.min) > -4194305 and int(d.max) < 2139095041, d.name


def test_statustext_chunks_long_texts() -> None:
    assert len(statustext(MAV, Severity.INFO, "short", 1)) == 1
    text = "x" * 120
    chunks = statustext(MAV, Severity.WARNING, text, 7)
    assert [c.chunk_seq for c in chunks] == [0, 1, 2] and {c.id for c in chunks} == {7}
    assert "".join(text_of(c.text) for c in chunks) == text
    exact = statustext(MAV, Severity.INFO, "y" * 100, 9)
    assert len(exact) == 3 and text_of(exact[-1].text) == ""  # a full last chunk gets a terminator


def _sp(mask: int, frame: int = 1, **kw: float) -> object:
    v = {k: kw.get(k, 0.0) for k in ("x", "y", "z", "vx", "vy", "vz", "afx", "afy", "afz", "yaw", "yaw_rate")}
    return MAV.set_position_target_local_ned_encode(0, 1, 1, frame, mask, *v.values())


def test_position_target_masks_and_frames() -> None:
    vel_only = 0b0000_1001_1100_0111  # MAVSDK set_velocity_ned: velocity and yaw
    sp = position_target(_sp(vel_only, vx=1.0, vy=2.0, vz=-0.5, yaw=0.3))
    assert not isinstance(sp, str)
    assert sp.position_m is None and sp.accel_m_s2 is None and sp.yaw_rate_rad_s is None
    assert sp.velocity_m_s == (1.0, 2.0, -0.5) and sp.yaw_rad == 0.3
    body = position_target(_sp(vel_only, frame=8, vx=1.0))
    assert not isinstance(body, str) and body.frame is OffboardFrame.BODY_NED
    pos = position_target(_sp(0b0000_1101_1111_1000, x=5.0, y=-2.0, z=-10.0))
    assert not isinstance(pos, str) and pos.position_m == (5.0, -2.0, -10.0) and pos.velocity_m_s is None
    assert "frame" in str(position_target(_sp(vel_only, frame=5)))
    assert "part of a vector" in str(position_target(_sp(0b110)))
    assert "NaN" in str(position_target(_sp(vel_only, vx=math.nan)))
    assert "force" in str(position_target(_sp(vel_only | 512)))


def test_attitude_target_conversion() -> None:
    t = attitude_target(MAV.set_attitude_target_encode(0, 1, 1, 0b111, [1.0, 0.0, 0.0, 0.0], 0, 0, 0, 0.6))
    assert not isinstance(t, str) and t.quat == (1.0, 0.0, 0.0, 0.0) and t.body_rates_rad_s is None and t.thrust == 0.6
    r = attitude_target(MAV.set_attitude_target_encode(0, 1, 1, 128, [1.0, 0.0, 0.0, 0.0], 0.1, 0.2, 0.3, 0.5))
    assert not isinstance(r, str) and r.quat is None and r.body_rates_rad_s == (0.1, 0.2, 0.3)
    assert isinstance(
        attitude_target(MAV.set_attitude_target_encode(0, 1, 1, 64 | 128 | 7, [1, 0, 0, 0], 0, 0, 0, 0)), str
    )


def test_streams_fall_due_on_sim_time_and_on_the_wall_clock_while_the_sim_stands_still() -> None:
    s = StreamScheduler(defaults={33: 100_000_000})
    assert s.due(0, 0) == [33]
    assert s.due(50_000_000, 50_000_000) == []
    assert s.due(100_000_000, 60_000_000) == []  # sim slow (x0.2) but moving: sim time alone, as PX4
    assert s.due(180_000_000, 60_000_000) == []  # stood still for 80 ms < the interval
    assert s.due(200_000_000, 60_000_000) == [33]  # still for a whole interval (paused): the wall clock
    assert s.next_due_wall_ns() == 300_000_000
    assert s.due(300_000_000, 60_000_000) == [33]  # still paused: on the wall clock's grid
    assert s.due(310_000_000, 160_000_000) == [33]  # sim period passed (sim faster than real time)
    assert s.next_due_wall_ns() == 410_000_000  # the sim moved at 310 ms
    assert s.due(400_000_000, 170_000_000) == []
    assert s.set_interval(33, -1) and s.due(10**10, 10**10) == [] and s.interval_us(33) == -1
    assert s.set_interval(105, 20_000) and s.interval_us(105) == 20_000
    assert s.set_interval(33, 0) and s.interval_us(33) == 100_000
    assert not s.set_interval(9999, 1000)


def test_heartbeat_schedule_wall_period_and_changes() -> None:
    h = HeartbeatSchedule()
    st0 = VehicleState()
    assert h.due(0, st0)
    assert not h.due(500_000_000, st0)
    assert h.due(1_000_000_000, st0)
    assert h.due(1_100_000_000, VehicleState(armed=True))
    assert h.due(1_200_000_000, VehicleState(armed=True, mode=FlightMode.TAKEOFF))
    assert not h.due(1_300_000_000, VehicleState(armed=True, mode=FlightMode.TAKEOFF))


def test_heartbeat_schedule_one_hertz_of_sim_time_when_the_sim_runs_fast() -> None:
    h = HeartbeatSchedule()
    assert h.due(0, VehicleState(t_ns=0))
    assert not h.due(10_000_000, VehicleState(t_ns=900_000_000))
    assert h.due(20_000_000, VehicleState(t_ns=1_000_000_000))  # x50: 1 s of sim in 20 ms of wall time
    assert h.next_due_sim_ns() == 2_000_000_000
    assert not h.due(30_000_000, VehicleState(t_ns=1_500_000_000))
    assert h.due(40_000_000, VehicleState(t_ns=2_010_000_000))


def test_peers_are_forgotten_after_ten_silent_seconds() -> None:
    link = UdpLink(LinkConfig("api", ("127.0.0.1", 0), ("127.0.0.1", 14540)))
    try:
        link.heard(("127.0.0.1", 40000), 0)
        assert set(link.destinations(9_000_000_000)) == {("127.0.0.1", 40000), ("127.0.0.1", 14540)}
        assert link.destinations(10_500_000_000) == [("127.0.0.1", 14540)]
    finally:
        link.close()


class _CountingActions(Actions):
    """The real action service, counting how often arm() runs."""

    arms = 0

    def arm(self, force: bool = False) -> CommandResult:
        self.arms += 1
        return super().arm(force)


def test_retransmission_is_not_executed_twice() -> None:
    real = Autopilot()
    counting = real.action = _CountingActions(real, real.offboard, real.manual_control, real.follow_me)
    svc = CommandService(real, lambda _i: None, lambda _i, _v: True)
    arm = (1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    sender = ("gcs",)
    first = svc.handle(CommandIn(400, arm), sender, 0)
    assert first.result.result.name == "DENIED"  # no sensor data yet: refused with a reason
    assert "Arming denied" in first.result.reason
    again = svc.handle(CommandIn(400, arm, confirmation=1), sender, 400_000_000)
    assert again.replayed and again.result == first.result and counting.arms == 1
    fresh = svc.handle(CommandIn(400, arm, confirmation=0), sender, 500_000_000)
    assert not fresh.replayed and counting.arms == 2
    late = svc.handle(CommandIn(400, arm, confirmation=2), sender, 5_000_000_000)
    assert not late.replayed and counting.arms == 3
    assert svc.handle(CommandIn(31000, arm), sender, 0).result.result.name == "UNSUPPORTED"


def test_mavftp_requests_get_a_nak_at_once() -> None:
    from harness.autopilot.mavlink.ftp import ERR_FILE_NOT_FOUND, OP_NAK, nak
    from harness.autopilot.mavlink.messages import Origin

    req = struct.pack("<HBBBBBBI", 41, 0, 4, 16, 0, 0, 0, 0) + b"@PARAM/param.pck"
    msg = MAV.file_transfer_protocol_encode(0, 1, 1, list(req) + [0] * (251 - len(req)))
    origin = Origin(0, ("127.0.0.1", 1), 255, 190)
    (out,) = nak(MAV, msg, origin)
    seq, _session, opcode, size, req_opcode = struct.unpack_from("<HBBBB", bytes(out.msg.payload))
    assert (seq, opcode, size, req_opcode) == (42, OP_NAK, 1, 4)
    assert out.msg.payload[12] == ERR_FILE_NOT_FOUND and out.to == origin and out.msg.target_system == 255
    reply = struct.pack("<HBBBBBBI", 42, 0, OP_NAK, 1, 4, 0, 0, 0)
    assert nak(MAV, MAV.file_transfer_protocol_encode(0, 1, 1, list(reply) + [0] * (251 - len(reply))), origin) == []


def test_global_setpoint_becomes_local_ned() -> None:
    from harness.autopilot.api import GeoPoint
    from harness.autopilot.mavlink.offboard import global_target

    lat0, lon0 = 47.397742, 8.545594
    state = VehicleState(
        pos_ned_m=(2.0, 3.0, -10.0), lat_deg=lat0, lon_deg=lon0, alt_amsl_m=498.0, home=GeoPoint(lat0, lon0, 488.0)
    )
    north_10m = math.degrees(10.0 / 6_371_000.0)
    pos_only = 0b0000_1101_1111_1000
    msg = MAV.set_position_target_global_int_encode(
        0, 1, 1, 6, pos_only, round((lat0 + north_10m) * 1e7), round(lon0 * 1e7), 15.0, 0, 0, 0, 0, 0, 0, 0, 0
    )
    sp = global_target(msg, state)
    assert not isinstance(sp, str) and sp.position_m is not None and sp.frame is OffboardFrame.LOCAL_NED
    n, e, d = sp.position_m
    assert abs(n - 12.0) < 0.02 and abs(e - 3.0) < 0.02 and abs(d - (-15.0)) < 1e-6  # 15 m above home
    bad = MAV.set_position_target_global_int_encode(0, 1, 1, 1, pos_only, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
    assert "frame" in str(global_target(bad, state))


def test_data_link_loss_acts_once_after_the_gcs_falls_silent() -> None:
    import numpy as np

    from harness.autopilot.mavlink.datalink import DataLinkMonitor
    from tests.autopilot.quadsim import QuadSim, fly

    ap = Autopilot()
    sim = QuadSim(np.random.default_rng(2))
    fly(ap, sim, 3.0)
    assert ap.action.arm().ok and ap.action.takeoff(3.0).ok
    fly(ap, sim, 6.0)
    mon = DataLinkMonitor(ap)
    s = ap.telemetry.state()
    assert s.in_air
    assert mon.check(s, 100 * 10**9) == "", "never heard a GCS: nothing lost"
    mon.heard_gcs(0)
    assert mon.check(s, 11 * 10**9) == "", "NAV_DLL_ACT 0: disabled"
    assert ap.params.set("NAV_DLL_ACT", 2).ok
    assert mon.check(s, 9 * 10**9) == ""
    assert mon.check(s, 11 * 10**9) == "Data link lost for 11 s: returning"
    assert mon.check(s, 12 * 10**9) == "", "once"
    fly(ap, sim, 0.1)
    assert ap.telemetry.state().mode is FlightMode.RTL


def test_parameters_survive_a_vehicle_restart_in_the_same_run_dir(tmp_path: object) -> None:
    from pathlib import Path

    from harness.autopilot.mavlink.param_store import persist_params, store_path
    from harness.autopilot.params import Params

    run_dir = Path(str(tmp_path))
    first = Params()
    assert persist_params(first, run_dir, 3) == []
    assert first.set("MIS_TAKEOFF_ALT", 12.5).ok and first.set("NAV_DLL_ACT", 2).ok
    assert not first.set("MIS_TAKEOFF_ALT", 1e9).ok  # refused: not saved
    again = Params()  # the vehicle restarts
    assert persist_params(again, run_dir, 3) == []
    assert again["MIS_TAKEOFF_ALT"] == 12.5 and again.get("NAV_DLL_ACT") == 2
    assert Params()["MIS_TAKEOFF_ALT"] != 12.5
    store_path(run_dir, 4).parent.mkdir(parents=True, exist_ok=True)
    store_path(run_dir, 4).write_text("{not json")
    assert persist_params(Params(), run_dir, 4) == []  # a corrupt file is ignored, not fatal
