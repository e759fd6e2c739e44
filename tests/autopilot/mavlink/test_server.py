"""The MAVLink server over real UDP, driven by a pymavlink ground station, with a real Autopilot that is
not stepping (a paused simulation): wall-clock liveness, identity, parameters, commands, streams."""

from __future__ import annotations

import itertools
import math
import socket
import struct
import time

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import FlightMode
from harness.autopilot.mavlink.server import DATAGRAMS_PER_LOOP
from harness.autopilot.mavlink.telemetry import SENSOR_GPS, SENSOR_GYRO, SENSOR_PREARM
from harness.autopilot.mavlink.transport import DATAGRAM_MAX, GREET_NS, pack_frames
from harness.autopilot.mavlink.version import CAPABILITIES
from harness.core.endpoints import LISTEN_HELLO, LISTEN_HELLO_WALL
from tests.autopilot.mavlink.conftest import Gcs, Rig

M = mavlink2


def test_heartbeat_on_wall_clock_while_sim_paused(gcs: Gcs, idle_rig: Rig) -> None:
    t_before = idle_rig.ap.telemetry.state().t_ns
    beats = gcs.collect(2.6, {"HEARTBEAT"})
    assert idle_rig.ap.telemetry.state().t_ns == t_before, "the autopilot must not have stepped"
    times = [t for t, _ in beats]
    assert len(times) >= 2, f"only {len(times)} heartbeats in 2.6 s of wall time"
    gaps = [(b - a) / 1e9 for a, b in itertools.pairwise(times)]
    assert max(gaps) <= 1.2
    hb = beats[0][1]
    assert hb.type == M.MAV_TYPE_QUADROTOR and hb.autopilot == M.MAV_AUTOPILOT_PX4
    assert hb.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED and not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.system_status == M.MAV_STATE_STANDBY
    assert hb.custom_mode == FlightMode.HOLD.custom_mode == (4 << 16) | (3 << 24)
    assert hb.get_srcSystem() == 1 and hb.get_srcComponent() == 1


def test_streams_flow_while_paused_and_time_boot_ms_is_sim_time(gcs: Gcs, idle_rig: Rig) -> None:
    msgs = gcs.collect(1.0, {"GLOBAL_POSITION_INT", "ATTITUDE", "VFR_HUD", "SYS_STATUS", "EXTENDED_SYS_STATE"})
    kinds = [m.get_type() for _, m in msgs]
    assert kinds.count("GLOBAL_POSITION_INT") >= 8 and kinds.count("ATTITUDE") >= 8
    assert 2 <= kinds.count("VFR_HUD") <= 6
    sim_ms = idle_rig.ap.telemetry.state().t_ns // 1_000_000
    assert {m.time_boot_ms for _, m in msgs if m.get_type() == "GLOBAL_POSITION_INT"} == {sim_ms}
    sys_status = next(m for _, m in msgs if m.get_type() == "SYS_STATUS")
    for bits in (sys_status.onboard_control_sensors_present, sys_status.onboard_control_sensors_health):
        assert bits & SENSOR_GYRO and bits & SENSOR_GPS and bits & SENSOR_PREARM
    ext = next(m for _, m in msgs if m.get_type() == "EXTENDED_SYS_STATE")
    assert ext.landed_state == M.MAV_LANDED_STATE_ON_GROUND
    alt = gcs.recv("ALTITUDE", 1.0)
    state = idle_rig.ap.telemetry.state()
    assert abs(alt.altitude_amsl - state.alt_amsl_m) < 1e-3 and abs(alt.altitude_relative - state.rel_alt_m) < 1e-3


def test_do_gripper_over_udp_is_acked_and_kept(gcs: Gcs, idle_rig: Rig) -> None:
    ack = gcs.command(mavlink2.MAV_CMD_DO_GRIPPER, 1, mavlink2.GRIPPER_ACTION_GRAB)
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED
    assert idle_rig.ap.telemetry.state().grippers_grabbed == (1,)
    ack = gcs.command(mavlink2.MAV_CMD_DO_GRIPPER, 1, mavlink2.GRIPPER_ACTION_RELEASE)
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED
    assert idle_rig.ap.telemetry.state().grippers_grabbed == ()


def test_autopilot_version_capabilities(gcs: Gcs, idle_rig: Rig) -> None:
    ack = gcs.command(512, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    assert ack.result == M.MAV_RESULT_ACCEPTED and ack.target_system == 245 and ack.target_component == 190
    v = gcs.recv("AUTOPILOT_VERSION")
    for cap in ("MISSION_INT", "COMMAND_INT", "MAVLINK2", "PARAM_ENCODE_BYTEWISE", "MISSION_FENCE", "MISSION_RALLY"):
        assert v.capabilities & getattr(M, "MAV_PROTOCOL_CAPABILITY_" + cap), cap
    assert v.capabilities == CAPABILITIES
    assert gcs.command(520).result == M.MAV_RESULT_ACCEPTED
    assert gcs.recv("AUTOPILOT_VERSION").uid == v.uid


def test_full_parameter_download_is_consistent(gcs: Gcs, idle_rig: Rig) -> None:
    gcs.send(gcs.mav.param_request_list_encode(1, 0))
    got = gcs.collect(1.5, {"PARAM_VALUE"})
    values = [m for _, m in got]
    expected = len(idle_rig.ap.params)
    assert {m.param_count for m in values} == {expected}
    assert sorted(m.param_index for m in values) == list(range(expected))
    names = {m.param_id: m for m in values}
    assert len(names) == expected
    for name in ("MIS_TAKEOFF_ALT", "RTL_RETURN_ALT", "MPC_XY_VEL_MAX", "NAV_DLL_ACT", "SYS_FAILURE_EN", "GF_ACTION"):
        assert name in names
    # INT32 bytewise in the float field, FLOAT as is
    nav = names["SYS_AUTOSTART"]
    assert nav.param_type == M.MAV_PARAM_TYPE_INT32
    assert struct.unpack("<i", struct.pack("<f", nav.param_value))[0] == 4001
    tko = names["MIS_TAKEOFF_ALT"]
    assert tko.param_type == M.MAV_PARAM_TYPE_REAL32 and math.isclose(
        tko.param_value, idle_rig.ap.params["MIS_TAKEOFF_ALT"], rel_tol=1e-6
    )
    # read by name (index -1) and by index agree with the list
    gcs.send(gcs.mav.param_request_read_encode(1, 1, b"RTL_RETURN_ALT", -1))
    by_name = gcs.recv("PARAM_VALUE", cond=lambda m: m.param_id == "RTL_RETURN_ALT")
    assert by_name.param_index == names["RTL_RETURN_ALT"].param_index
    gcs.send(gcs.mav.param_request_read_encode(1, 1, b"", by_name.param_index))
    by_index = gcs.recv("PARAM_VALUE", cond=lambda m: m.param_index == by_name.param_index)
    assert by_index.param_id == "RTL_RETURN_ALT"


def _int_as_float(v: int) -> float:
    return float(struct.unpack("<f", struct.pack("<i", v))[0])


def test_param_set_is_echoed_with_same_type_and_value(gcs: Gcs, idle_rig: Rig) -> None:
    gcs.send(gcs.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 7.5, M.MAV_PARAM_TYPE_REAL32))
    echo = gcs.recv("PARAM_VALUE", cond=lambda m: m.param_id == "MIS_TAKEOFF_ALT")
    assert echo.param_value == 7.5 and echo.param_type == M.MAV_PARAM_TYPE_REAL32
    assert idle_rig.ap.params["MIS_TAKEOFF_ALT"] == 7.5
    # a negative INT32 travels bytewise (its bit pattern is a NaN as a float)
    gcs.send(gcs.mav.param_set_encode(1, 1, b"SYS_HITL", _int_as_float(-1), M.MAV_PARAM_TYPE_INT32))
    echo = gcs.recv("PARAM_VALUE", cond=lambda m: m.param_id == "SYS_HITL")
    assert echo.param_type == M.MAV_PARAM_TYPE_INT32
    assert struct.unpack("<i", struct.pack("<f", echo.param_value))[0] == -1
    assert idle_rig.ap.params.get("SYS_HITL") == -1
    # FLW_TGT_FA is a FLOAT, as in PX4 and as MAVSDK's follow_me.set_config sets it
    gcs.send(gcs.mav.param_set_encode(1, 1, b"FLW_TGT_FA", -120.0, M.MAV_PARAM_TYPE_REAL32))
    echo = gcs.recv("PARAM_VALUE", cond=lambda m: m.param_id == "FLW_TGT_FA")
    assert echo.param_type == M.MAV_PARAM_TYPE_REAL32 and echo.param_value == -120.0
    # out of range: refused, echoed unchanged, with a reason
    gcs.send(gcs.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 5000.0, M.MAV_PARAM_TYPE_REAL32))
    echo = gcs.recv("PARAM_VALUE", cond=lambda m: m.param_id == "MIS_TAKEOFF_ALT")
    assert echo.param_value == 7.5
    assert "MIS_TAKEOFF_ALT" in gcs.recv("STATUSTEXT").text


def test_commands_are_acked_unsupported_and_refusals_have_reasons(gcs: Gcs, idle_rig: Rig) -> None:
    assert gcs.command(31000).result == M.MAV_RESULT_UNSUPPORTED  # MAV_CMD_USER_1
    assert gcs.command(246, 3.0).result == M.MAV_RESULT_UNSUPPORTED  # reboot to the bootloader: not simulated
    assert gcs.command(241, 0, 0, 1).result == M.MAV_RESULT_UNSUPPORTED  # baro calibration: not simulated
    ack = gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0.5)
    assert ack.result == M.MAV_RESULT_DENIED
    assert "param1" in gcs.recv("STATUSTEXT").text
    ack = gcs.command(M.MAV_CMD_DO_CHANGE_SPEED, 1.0, math.nan)
    assert ack.result == M.MAV_RESULT_DENIED
    assert gcs.command(M.MAV_CMD_DO_ORBIT, math.inf, 2.0).result == M.MAV_RESULT_DENIED
    assert gcs.command(M.MAV_CMD_DO_REPOSITION, -1, 1, 0, math.nan, 95.0, 8.0, 500.0).result == M.MAV_RESULT_DENIED
    ack = gcs.command(420, 0, 1, 0)
    assert ack.result == M.MAV_RESULT_DENIED
    assert "SYS_FAILURE_EN" in gcs.recv("STATUSTEXT").text
    # a mode the autopilot lacks; then a real mode change is followed at once by a heartbeat
    assert gcs.command(M.MAV_CMD_DO_SET_MODE, 1, 1, 0).result == M.MAV_RESULT_DENIED  # MANUAL: no RC
    assert gcs.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == M.MAV_RESULT_DENIED  # OFFBOARD: no setpoint
    c = idle_rig.server.counters()
    assert c.commands["UNSUPPORTED"] == 3 and c.commands["DENIED"] >= 6
    assert c.commands_by_id[M.MAV_CMD_COMPONENT_ARM_DISARM] == {"DENIED": 1}


def test_retransmitted_command_is_answered_not_repeated(gcs: Gcs, idle_rig: Rig) -> None:
    first = gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    assert first.result == M.MAV_RESULT_ACCEPTED
    again = gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, confirmation=1)
    assert again.result == first.result
    idle_rig.step_s(0.1)  # commands take effect at the next autopilot step
    assert gcs.recv("HEARTBEAT", 1.5, lambda m: m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0.0).result == M.MAV_RESULT_ACCEPTED
    idle_rig.step_s(0.1)
    hb = gcs.recv("HEARTBEAT", 1.5, lambda m: not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
    assert hb.system_status == M.MAV_STATE_STANDBY
    assert not idle_rig.ap.telemetry.state().armed


def test_set_message_interval_and_request_message(gcs: Gcs, idle_rig: Rig) -> None:
    assert gcs.command(511, M.MAVLINK_MSG_ID_HIGHRES_IMU, 20_000).result == M.MAV_RESULT_ACCEPTED  # 50 Hz
    assert gcs.command(511, M.MAVLINK_MSG_ID_ATTITUDE, -1).result == M.MAV_RESULT_ACCEPTED
    assert gcs.command(511, 9999, 1000).result == M.MAV_RESULT_UNSUPPORTED
    gcs.collect(0.2)
    kinds = [m.get_type() for _, m in gcs.collect(1.0, {"HIGHRES_IMU", "ATTITUDE"})]
    assert kinds.count("HIGHRES_IMU") >= 30 and kinds.count("ATTITUDE") == 0
    assert gcs.command(511, M.MAVLINK_MSG_ID_ATTITUDE, 0).result == M.MAV_RESULT_ACCEPTED  # default again
    assert gcs.recv("ATTITUDE", 1.0)
    assert gcs.command(512, M.MAVLINK_MSG_ID_HOME_POSITION).result in (
        M.MAV_RESULT_ACCEPTED,
        M.MAV_RESULT_TEMPORARILY_REJECTED,
    )
    assert gcs.command(512, 12345).result == M.MAV_RESULT_UNSUPPORTED


def test_ping_and_home_before_arming(gcs: Gcs, idle_rig: Rig) -> None:
    gcs.send(gcs.mav.ping_encode(123456, 42, 0, 0))
    pong = gcs.recv("PING", cond=lambda m: m.seq == 42)
    assert pong.time_usec == 123456 and pong.target_system == 245
    # like PX4, home is set at the first good global position, before arming (MAVSDK waits for it)
    state = idle_rig.ap.telemetry.state()
    assert state.home is not None and not state.armed
    assert gcs.command(512, M.MAVLINK_MSG_ID_HOME_POSITION).result == M.MAV_RESULT_ACCEPTED
    home = gcs.recv("HOME_POSITION")
    assert abs(home.latitude - round(state.home.lat_deg * 1e7)) <= 1
    assert home.altitude == round(state.home.alt_amsl_m * 1000)
    assert gcs.command(410).result == M.MAV_RESULT_ACCEPTED  # the old GET_HOME_POSITION
    assert gcs.recv("HOME_POSITION").latitude == home.latitude


def test_timesync_answers_on_the_time_base_of_the_telemetry(gcs: Gcs, idle_rig: Rig) -> None:
    """TIMESYNC's tc1 is sim time since boot, the base of every time_boot_ms: a ground station that aligns its
    clock with TIMESYNC is within one step of the telemetry (before: the host's uptime, thousands of seconds)."""
    att = gcs.recv("ATTITUDE")
    gcs.send(gcs.mav.timesync_encode(0, 987_654_321))
    answer = gcs.recv("TIMESYNC", cond=lambda m: m.ts1 == 987_654_321)
    after = gcs.recv("ATTITUDE")
    assert att.time_boot_ms * 1_000_000 <= answer.tc1 <= after.time_boot_ms * 1_000_000 + 4_000_000
    assert abs(answer.tc1 - idle_rig.ap.telemetry.state().t_ns) < 1_000_000_000


def test_gcs_port_and_api_port_both_serve_and_set_mode_message(gcs: Gcs) -> None:
    """Vehicle 2 (sysid 3): its API link sends to api_port_base + 2, its GCS link to the GCS port; both
    answer; the SET_MODE message (no ACK) changes the mode; the other GCS sees it."""
    import numpy as np

    from harness.autopilot.autopilot import Autopilot, AutopilotConfig
    from harness.autopilot.mavlink import MavlinkServer, PortsConfig
    from tests.autopilot.quadsim import QuadSim, fly

    qgc = Gcs(sysid=255, compid=190)
    ap = Autopilot(AutopilotConfig(vehicle=2))
    sim = QuadSim(np.random.default_rng(4))
    fly(ap, sim, 3.0)
    server = MavlinkServer(ap, 2, PortsConfig(api_port_base=gcs.port - 2, gcs_port=qgc.port)).start()
    try:
        hb_api = gcs.connect()
        hb_gcs = qgc.connect()
        assert hb_api.get_srcSystem() == hb_gcs.get_srcSystem() == 3
        assert gcs.server != qgc.server, "one socket per link"
        ack = qgc.command(512, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, target=3)
        assert ack.result == M.MAV_RESULT_ACCEPTED and ack.target_system == 255
        pos = FlightMode.POSCTL.custom_mode
        # position mode without stick input: refused as PX4 refuses it, reason to every GCS
        gcs.send(gcs.mav.set_mode_encode(3, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, pos))
        assert "manual control" in qgc.recv("STATUSTEXT", 2.0).text
        gcs.send(gcs.mav.manual_control_encode(3, 0, 0, 500, 0, 0))  # centred sticks
        gcs.collect(0.2)
        gcs.send(gcs.mav.set_mode_encode(3, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, pos))
        gcs.collect(0.2)
        fly(ap, sim, 0.1)  # the mode applies at the next step
        assert qgc.recv("HEARTBEAT", 2.0, lambda m: m.custom_mode == pos)
        # a command for another system is not ours: no ACK, counted
        gcs.send(gcs.mav.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
        gcs.collect(0.3)
        assert server.counters().not_for_us >= 1
    finally:
        server.stop()
        qgc.close()


def _consecutive_gcs(n: int) -> list[Gcs]:
    """``n`` ground stations on consecutive UDP ports (like scripts on 14540, 14541, ...)."""
    import socket

    for _ in range(50):
        first = Gcs()
        base = first.port
        out = [first]
        try:
            for i in range(1, n):
                g = Gcs()
                g.sock.close()
                g.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                out.append(g)
                g.sock.bind(("127.0.0.1", base + i))
            return out
        except OSError:
            for g in out:
                g.close()
    raise AssertionError("no consecutive free UDP ports")


def test_three_vehicles_each_reach_their_own_script_port() -> None:
    """Vehicle i sends to api_port_base + i: three scripts on three consecutive ports each see one vehicle."""
    from harness.autopilot.autopilot import Autopilot, AutopilotConfig
    from harness.autopilot.mavlink import MavlinkServer, PortsConfig

    scripts = _consecutive_gcs(3)
    ports = PortsConfig(api_port_base=scripts[0].port, gcs_port=0)
    servers = [MavlinkServer(Autopilot(AutopilotConfig(vehicle=i)), i, ports).start() for i in range(3)]
    try:
        for i, g in enumerate(scripts):
            seen = {m.get_srcSystem() for _, m in g.collect(1.1, {"HEARTBEAT"})}
            assert seen == {i + 1}
            g.send(g.mav.command_long_encode(i + 1, 1, 512, 0, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0))
            ack = g.recv("COMMAND_ACK", 2.0)
            assert ack.get_srcSystem() == i + 1 and ack.result == M.MAV_RESULT_ACCEPTED
    finally:
        for srv in servers:
            srv.stop()
        for g in scripts:
            g.close()


def test_frames_of_one_instant_share_a_datagram_in_order(gcs: Gcs, idle_rig: Rig) -> None:
    """The telemetry due at one instant reaches a peer as one datagram (one ``sendto`` per destination, as
    ArduPilot's UDP ports send), under DATAGRAM_MAX, with every frame in sequence: none lost or reordered."""
    gcs.keep_raw = True
    gcs.collect(1.5, {"GLOBAL_POSITION_INT"})
    gcs.keep_raw = False
    parser = mavlink2.MAVLink(None)
    per_datagram = []
    seqs = []
    for data in gcs.raw:
        assert len(data) <= DATAGRAM_MAX
        frames = [m for m in parser.parse_buffer(data) or [] if not isinstance(m, mavlink2.MAVLink_bad_data)]
        per_datagram.append([m.get_type() for m in frames])
        seqs += [m.get_seq() for m in frames if m.get_srcSystem() == 1 and m.get_srcComponent() == 1]  # (per component)
    assert max(len(kinds) for kinds in per_datagram) >= 4, per_datagram[:10]
    together = [kinds for kinds in per_datagram if "GLOBAL_POSITION_INT" in kinds]
    assert together and all("ATTITUDE" in kinds for kinds in together), together[:5]
    assert all((b - a) % 256 == 1 for a, b in itertools.pairwise(seqs)), seqs[:40]


def test_pack_frames_fills_datagrams_in_order_and_never_splits_a_frame() -> None:
    frames = [bytes([i]) * n for i, n in enumerate((600, 500, 300, 280, 1500, 10))]
    packed = list(pack_frames(frames, limit=1400))
    assert [n for _, n in packed] == [3, 1, 1, 1]
    assert [len(d) for d, _ in packed] == [1400, 280, 1500, 10]
    assert b"".join(d for d, _ in packed) == b"".join(frames)
    assert list(pack_frames([b"x"])) == [(b"x", 1)]


def test_an_announced_mavsdk_port_is_greeted_until_it_answers(gcs: Gcs, idle_rig: Rig) -> None:
    """A mission's MAVSDK listens on a port its runtime announced (``LISTEN_HELLO_WALL``; MAVSDK's own
    ``udpout`` binds port 0 with SO_REUSEADDR, which Linux may give two missions alike): the vehicle sends
    it heartbeats every GREET_NS from the announcement on, and everything else once it has answered."""
    vehicle = idle_rig.server.links[0].local_address
    listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        listener.bind(("127.0.0.1", 0))
        listener.sendto(LISTEN_HELLO_WALL, vehicle)
        parser = mavlink2.MAVLink(None)
        beats = []
        listener.settimeout(0.05)
        deadline = time.monotonic() + 0.5
        while time.monotonic() < deadline:
            try:
                data = listener.recv(65535)
            except TimeoutError:
                continue
            beats += [(time.monotonic(), m) for m in parser.parse_buffer(data) or [] if m.get_type() == "HEARTBEAT"]
        assert len(beats) >= 5, f"{len(beats)} heartbeats in 0.5 s: not greeted every {GREET_NS / 1e6:g} ms"
        assert beats[0][1].get_srcSystem() == 1
        # it answers (as MAVSDK does, with its heartbeat): no more greetings, but its streams like any peer's
        mav = mavlink2.MAVLink(None, 245, 190)
        listener.sendto(mav.heartbeat_encode(6, 8, 0, 0, 0).pack(mav), vehicle)
        time.sleep(0.1)
        kinds: list[str] = []
        deadline = time.monotonic() + 1.2
        while time.monotonic() < deadline:
            try:
                kinds += [m.get_type() for m in parser.parse_buffer(listener.recv(65535)) or []]
            except TimeoutError:
                continue
        assert "GLOBAL_POSITION_INT" in kinds and kinds.count("HEARTBEAT") <= 3, kinds.count("HEARTBEAT")
    finally:
        listener.close()


def test_a_missions_burst_waits_for_the_next_loop_however_long_phase_0_lasts(gcs: Gcs, idle_rig: Rig) -> None:
    """A mission on sim time (its socket announced with ``LISTEN_HELLO``) gets ``DATAGRAMS_PER_LOOP`` datagrams
    handled per autopilot loop; the rest wait for the next step, also after seconds of wall time (a phase 0 on a
    loaded machine: handling them on a wall-clock limit flew a mission upload a tick early, another flight). A
    ground station beside it is answered at once meanwhile."""
    vehicle = idle_rig.server.links[0].local_address
    mission = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        mission.bind(("127.0.0.1", 0))
        mission.sendto(LISTEN_HELLO, vehicle)
        mav = mavlink2.MAVLink(None, 245, 190)
        commands = [50_000 + k for k in range(DATAGRAMS_PER_LOOP + 4)]
        for c in commands:
            mission.sendto(mav.command_long_encode(1, 1, c, 0, 0, 0, 0, 0, 0, 0, 0).pack(mav), vehicle)

        def acks(wait_s: float) -> list[int]:
            parser, got = mavlink2.MAVLink(None), []
            mission.settimeout(0.05)
            deadline = time.monotonic() + wait_s
            while time.monotonic() < deadline:
                try:
                    data = mission.recv(65535)
                except TimeoutError:
                    continue
                got += [m.command for m in parser.parse_buffer(data) or [] if m.get_type() == "COMMAND_ACK"]
            return got

        assert acks(1.0) == commands[:DATAGRAMS_PER_LOOP]
        assert gcs.command(31000).result == M.MAV_RESULT_UNSUPPORTED  # the ground station does not wait
        assert acks(0.5) == [], "the rest must wait for the autopilot's next loop, not a wall-clock limit"
        idle_rig.step_s(0.02)
        assert acks(0.5) == commands[DATAGRAMS_PER_LOOP:]
    finally:
        mission.close()
