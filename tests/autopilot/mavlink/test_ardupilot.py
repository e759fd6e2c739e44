"""The ArduCopter personality: its pure parts, then the server over real TCP with pymavlink as ArduPilot
scripts use it (``tcp:127.0.0.1:<SERIAL0>``), on a real Autopilot flown by the test quad at 4x real time."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as apm
from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import FlightMode, GeoPoint, MavCmd, MavFrame, MissionItem, VehicleState
from harness.autopilot.firmware import Firmware, firmware_of
from harness.autopilot.mavlink import MavlinkServer, PortsConfig
from harness.autopilot.mavlink.ardupilot.adapter import home_item
from harness.autopilot.mavlink.ardupilot.modes import CopterMode, ModeTracker
from harness.autopilot.mavlink.ardupilot.params import CopterParams
from harness.autopilot.mavlink.ardupilot.streams import ekf_flags
from harness.autopilot.mavlink.personality import core_param_defaults
from harness.autopilot.mavlink.tcp import take_frames
from harness.autopilot.params import Params
from harness.core.errors import ScenarioError
from harness.core.geo import quat_from_euler
from tests.autopilot.mavlink.conftest import Gcs, Rig
from tests.helpers import free_tcp_port, wait_until

M = mavlink2


# ---------------------------------------------------------------------- pure parts
def test_mode_tracker_shows_the_mode_asked_for_until_the_core_leaves_it() -> None:
    t = ModeTracker()
    assert t.shown(FlightMode.HOLD) is CopterMode.STABILIZE  # ArduCopter boots in STABILIZE
    t.select(CopterMode.GUIDED)
    for core in (FlightMode.HOLD, FlightMode.TAKEOFF, FlightMode.OFFBOARD, FlightMode.HOLD):
        assert t.shown(core) is CopterMode.GUIDED
    assert t.shown(FlightMode.RTL) is CopterMode.RTL  # a failsafe return: the shown mode follows the core
    assert t.shown(FlightMode.HOLD) is CopterMode.LOITER
    t.select(CopterMode.AUTO)
    assert t.shown(FlightMode.MISSION) is CopterMode.AUTO
    assert t.shown(FlightMode.HOLD) is CopterMode.AUTO  # ArduCopter stays in AUTO at the end of a mission


def test_firmware_names_and_defaults() -> None:
    assert Firmware.parse(" ArduPilot ") is Firmware.ARDUPILOT
    with pytest.raises(ScenarioError, match=r"unknown firmware 'apm'.*px4, ardupilot"):
        Firmware.parse("apm", "--firmware")
    fws = (Firmware.PX4, Firmware.ARDUPILOT)
    assert [firmware_of(fws, i) for i in range(3)] == [Firmware.PX4, Firmware.ARDUPILOT, Firmware.PX4]
    assert firmware_of((Firmware.ARDUPILOT,), 7) is Firmware.ARDUPILOT and firmware_of((), 0) is Firmware.PX4
    assert core_param_defaults(Firmware.ARDUPILOT)["RTL_RETURN_ALT"] == 15.0 and not core_param_defaults(Firmware.PX4)


def test_ardupilot_parameters_follow_the_core_both_ways_in_ardupilot_units() -> None:
    core = Params(overrides=core_param_defaults(Firmware.ARDUPILOT))
    ap = CopterParams(core, sysid=3)
    assert ap["RTL_ALT"] == 1500.0 and ap["SYSID_THISMAV"] == 3 and ap["WPNAV_SPEED"] == 500.0
    assert ap.set("RTL_ALT", 2500).ok and core["RTL_RETURN_ALT"] == 25.0
    assert core.set("MPC_XY_CRUISE", 7.5).ok and ap["WPNAV_SPEED"] == 750.0
    refused = ap.set("WPNAV_SPEED", 5)  # below ArduCopter's 10..2000 cm/s
    assert not refused.ok and "WPNAV_SPEED" in refused.reason and ap["WPNAV_SPEED"] == 750.0
    assert core["MPC_XY_CRUISE"] == 7.5
    assert not ap.set("SYSID_THISMAV", 9).ok
    assert ap.set("FENCE_RADIUS", 200).ok and core["GF_MAX_HOR_DIST"] == 0.0  # fence still disabled
    assert ap.set("FENCE_ENABLE", 1).ok and core["GF_MAX_HOR_DIST"] == 200.0 and core["GF_MAX_VER_DIST"] == 100.0
    assert ap.set("FENCE_ENABLE", 0).ok and core["GF_MAX_HOR_DIST"] == 0.0


def test_ardupilot_ranges_beyond_the_core_are_kept_as_set_and_flown_clamped() -> None:
    """ArduCopter takes THR_MIN 0..300 (0.1 %; DroneKit's vehicle_state.py writes 10) and WPNAV_SPEED from
    10 cm/s: the value reads back as set, the core flies the nearest value it takes."""
    core = Params(overrides=core_param_defaults(Firmware.ARDUPILOT))
    ap = CopterParams(core, sysid=1)
    assert ap["THR_MIN"] == 80.0
    assert ap.set("THR_MIN", 10).ok and ap["THR_MIN"] == 10.0 and core["MPC_THR_MIN"] == 0.05
    assert ap.set("THR_MIN", 120).ok and ap["THR_MIN"] == 120.0 and core["MPC_THR_MIN"] == 0.12
    refused = ap.set("THR_MIN", 600)  # above both ranges (the core takes up to 500)
    assert not refused.ok and "THR_MIN" in refused.reason and ap["THR_MIN"] == 120.0
    assert ap.set("WPNAV_SPEED", 100).ok and ap["WPNAV_SPEED"] == 100.0 and core["MPC_XY_CRUISE"] == 3.0
    assert ap.set("LAND_SPEED", 50).ok and ap["LAND_SPEED"] == 50.0 and core["MPC_LAND_SPEED"] == 0.6
    assert core.set("MPC_THR_MIN", 0.2).ok and ap["THR_MIN"] == 200.0  # a core change still shows


def test_ekf_flags_say_when_dronekit_may_arm() -> None:
    from harness.autopilot.api import Health

    bad = VehicleState(health=Health(gyro_ok=True, accel_ok=True))
    good = VehicleState(health=Health(gyro_ok=True, accel_ok=True, gps_ok=True, local_position_ok=True))
    assert ekf_flags(bad) & apm.EKF_CONST_POS_MODE and not ekf_flags(bad) & apm.EKF_PRED_POS_HORIZ_ABS
    assert ekf_flags(good) & apm.EKF_PRED_POS_HORIZ_ABS and ekf_flags(good) & apm.EKF_POS_HORIZ_ABS
    assert not ekf_flags(good) & apm.EKF_CONST_POS_MODE


def test_home_item_is_mission_item_zero() -> None:
    it = home_item(GeoPoint(47.5, 8.5, 500.0))
    assert (it.seq, it.command, it.frame, it.x, it.y, it.z) == (
        0,
        MavCmd.NAV_WAYPOINT,
        MavFrame.GLOBAL,
        475e6,
        85e6,
        500,
    )
    assert home_item(None).x == 0


def _frame(mav: mavlink2.MAVLink, i: int) -> bytes:
    return bytes(mav.command_long_encode(1, 1, 400 + i, 0, 1, 2, 3, 4, 5, 6, 7).pack(mav))


@given(cuts=st.lists(st.integers(min_value=0, max_value=400), max_size=12), junk=st.binary(max_size=5))
def test_take_frames_reassembles_a_tcp_stream_cut_anywhere(cuts: list[int], junk: bytes) -> None:
    mav = mavlink2.MAVLink(None, 1, 1)
    frames = [_frame(mav, i) for i in range(8)]
    stream = junk.replace(b"\xfd", b"").replace(b"\xfe", b"") + b"".join(frames)
    buf, got = bytearray(), []
    prev = 0
    for c in [*sorted(min(c, len(stream)) for c in cuts), len(stream)]:
        buf += stream[prev:c]
        prev = c
        got += take_frames(buf)
    assert got == frames and not buf


# ---------------------------------------------------------------------- over TCP
class Client:
    """pymavlink over TCP, as an ArduPilot script connects to SITL's SERIAL0."""

    def __init__(self, port: int) -> None:
        self.conn: Any = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=255, dialect="ardupilotmega")

    def recv(self, kind: str | list[str], timeout_s: float = 5.0, cond: Any = None) -> Any:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            m = self.conn.recv_match(type=kind, blocking=True, timeout=0.2)
            if m is not None and (cond is None or cond(m)):
                return m
        raise AssertionError(f"no {kind} within {timeout_s} s")

    def command(self, command: int, *params: float, timeout_s: float = 5.0) -> Any:
        p = [*params, *([0.0] * (7 - len(params)))]
        self.conn.mav.command_long_send(1, 1, command, 0, *p)
        return self.recv("COMMAND_ACK", timeout_s, lambda m: m.command == command)

    def mode(self, name: str) -> Any:
        number = self.conn.mode_mapping()[name]
        return self.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, number)

    def close(self) -> None:
        self.conn.close()


@pytest.fixture
def copter(gcs: Gcs) -> Iterator[tuple[Rig, Client, int]]:
    rig = Rig(gcs, speed=4.0, **core_param_defaults(Firmware.ARDUPILOT))
    rig.server.stop()
    port = free_tcp_port()
    ports = PortsConfig(api_port_base=gcs.port, gcs_port=0, tcp_port_base=port)
    rig.server = MavlinkServer(rig.ap, 0, ports, firmware=Firmware.ARDUPILOT)
    rig.start()
    client = Client(port)
    yield rig, client, port
    client.close()
    rig.stop()


def test_identity_modes_and_a_guided_flight_over_tcp(copter: tuple[Rig, Client, int]) -> None:
    rig, c, _port = copter
    hb = c.recv("HEARTBEAT")
    assert (hb.autopilot, hb.type, hb.custom_mode) == (M.MAV_AUTOPILOT_ARDUPILOTMEGA, M.MAV_TYPE_QUADROTOR, 0)
    c.conn.mav.request_data_stream_send(1, 1, M.MAV_DATA_STREAM_ALL, 4, 1)
    ekf = c.recv("EKF_STATUS_REPORT", 5.0, lambda m: m.flags & apm.EKF_PRED_POS_HORIZ_ABS)
    assert not ekf.flags & apm.EKF_CONST_POS_MODE
    v = c.command(M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1)
    assert v.result == M.MAV_RESULT_ACCEPTED
    version = c.recv("AUTOPILOT_VERSION")
    assert version.flight_sw_version >> 24 == 4 and version.capabilities & M.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT

    ack = c.command(M.MAV_CMD_DO_SET_MODE, 1, CopterMode.SPORT)
    assert ack.result == M.MAV_RESULT_DENIED
    text = c.recv("STATUSTEXT", 3.0, lambda m: "SPORT" in m.text)
    assert "not flown here" in text.text
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 5).result == M.MAV_RESULT_DENIED  # not armed
    assert c.mode("AUTO").result == M.MAV_RESULT_DENIED  # no mission
    assert c.mode("GUIDED").result == M.MAV_RESULT_ACCEPTED
    c.recv("HEARTBEAT", 3.0, lambda m: m.custom_mode == CopterMode.GUIDED)
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 5).result == M.MAV_RESULT_ACCEPTED
    c.recv("GLOBAL_POSITION_INT", 30.0, lambda m: m.relative_alt > 4700)  # 5 m above home, not AMSL
    hb = c.recv("HEARTBEAT")
    assert hb.custom_mode == CopterMode.GUIDED and hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED

    # simple_goto: MISSION_ITEM current=2, relative altitude
    s = rig.ap.telemetry.state()
    lat, lon = s.lat_deg + 10 / 111_195, s.lon_deg
    c.conn.mav.mission_item_send(1, 1, 0, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, 16, 2, 0, 0, 0, 0, 0, lat, lon, 8)
    assert c.recv("MISSION_ACK").type == M.MAV_MISSION_ACCEPTED
    c.recv("GLOBAL_POSITION_INT", 40.0, lambda m: abs(m.lat * 1e-7 - lat) * 111_195 < 1.0 and m.relative_alt > 7500)
    # CONDITION_YAW 90 absolute
    assert c.command(115, 90, 30, 1, 0).result == M.MAV_RESULT_ACCEPTED
    c.recv("ATTITUDE", 30.0, lambda m: abs(math.degrees(m.yaw) - 90) < 5)
    # velocity target (DroneKit's send_ned_velocity mask): east at 2 m/s
    for _ in range(6):
        c.conn.mav.set_position_target_local_ned_send(0, 1, 1, 1, 0b0000111111000111, 0, 0, 0, 0, 2, 0, 0, 0, 0, 0, 0)
        m = c.recv("LOCAL_POSITION_NED", 1.0)
    assert m.vy > 1.0
    assert c.recv("HEARTBEAT").custom_mode == CopterMode.GUIDED
    # DO_REPOSITION (QGC's "go to" on ArduPilot): from LOITER only with the change-mode flag, then GUIDED
    assert c.mode("LOITER").result == M.MAV_RESULT_ACCEPTED
    s = rig.ap.telemetry.state()
    lat_int, lon_int = round((s.lat_deg - 8 / 111_195) * 1e7), round(s.lon_deg * 1e7)

    def reposition(flags: int) -> Any:
        c.conn.mav.command_int_send(1, 1, 6, 192, 0, 0, -1, flags, 0, math.nan, lat_int, lon_int, 9)
        return c.recv("COMMAND_ACK", 5.0, lambda m: m.command == 192)

    assert reposition(0).result == M.MAV_RESULT_DENIED
    assert reposition(1).result == M.MAV_RESULT_ACCEPTED
    c.recv("HEARTBEAT", 3.0, lambda m: m.custom_mode == CopterMode.GUIDED)
    c.recv("GLOBAL_POSITION_INT", 40.0, lambda m: abs(m.lat - lat_int) * 0.0111195 < 1.0 and m.relative_alt > 8500)
    assert c.mode("RTL").result == M.MAV_RESULT_ACCEPTED
    c.recv("HEARTBEAT", 3.0, lambda m: m.custom_mode == CopterMode.RTL)


def test_mission_with_home_at_item_zero_float_and_int(copter: tuple[Rig, Client, int]) -> None:
    rig, c, port = copter
    c.recv("HEARTBEAT")
    s = rig.ap.telemetry.state()
    c.conn.waypoint_clear_all_send()
    c.conn.waypoint_count_send(3)
    items = [
        (0, M.MAV_FRAME_GLOBAL, 16, s.lat_deg, s.lon_deg, 0.0),  # home: ignored by the vehicle
        (1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, 22, 0.0, 0.0, 10.0),
        (2, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, 16, s.lat_deg + 1e-4, s.lon_deg, 10.0),
    ]
    for _ in items:
        req = c.recv("MISSION_REQUEST")  # ArduPilot asks with the float request (DroneKit answers nothing else)
        seq, frame, cmd, x, y, z = items[req.seq]
        c.conn.mav.mission_item_send(1, 1, seq, frame, cmd, 0, 1, 0, 0, 0, 0, x, y, z)
    assert c.recv("MISSION_ACK").type == M.MAV_MISSION_ACCEPTED
    core = rig.ap.mission.download()
    assert [(it.seq, it.command) for it in core] == [(0, 22), (1, 16)]

    other = Client(port)  # a second client on the same TCP port downloads it, int form
    try:
        other.conn.mav.mission_request_list_send(1, 1)
        assert other.recv("MISSION_COUNT").count == 3
        other.conn.mav.mission_request_int_send(1, 1, 0)
        home = other.recv("MISSION_ITEM_INT")
        assert home.seq == 0 and abs(home.x * 1e-7 - s.home.lat_deg) < 1e-6  # type: ignore[union-attr]
        other.conn.mav.mission_request_send(1, 1, 2)
        wp = other.recv("MISSION_ITEM")
        assert wp.seq == 2 and abs(wp.x - (s.lat_deg + 1e-4)) < 1e-5 and wp.z == 10.0  # float32 degrees
    finally:
        other.close()
    c.conn.waypoint_set_current_send(2)
    c.recv("MISSION_CURRENT", 3.0, lambda m: m.seq == 2)
    assert rig.ap.telemetry.state().mission.current_seq == 1


def test_parameters_by_ardupilot_names_as_c_cast_floats(copter: tuple[Rig, Client, int]) -> None:
    rig, c, _port = copter
    c.recv("HEARTBEAT")
    c.conn.mav.param_request_read_send(1, 1, b"SYSID_THISMAV", -1)
    p = c.recv("PARAM_VALUE", 3.0, lambda m: m.param_id == "SYSID_THISMAV")
    assert p.param_value == 1.0 and p.param_type == M.MAV_PARAM_TYPE_INT32  # the value itself, not its bits
    c.conn.mav.param_set_send(1, 1, b"RTL_ALT", 2000.0, M.MAV_PARAM_TYPE_REAL32)
    echo = c.recv("PARAM_VALUE", 3.0, lambda m: m.param_id == "RTL_ALT")
    assert echo.param_value == 2000.0 and rig.ap.params["RTL_RETURN_ALT"] == 20.0
    c.conn.mav.request_data_stream_send(1, 1, M.MAV_DATA_STREAM_POSITION, 2, 1)
    c.recv("PARAM_VALUE", 3.0, lambda m: m.param_id == "SR0_POSITION" and m.param_value == 2.0)
    c.recv("GLOBAL_POSITION_INT")
    got = []
    end = time.monotonic() + 2.0
    while time.monotonic() < end:
        m = c.conn.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=0.2)
        if m is not None:
            got.append(m.time_boot_ms)
    # 2 Hz on the faster of the sim (x4) and the wall clock: about 8 messages per wall second, not 40
    assert 4 <= len(got) <= 24, got


def test_unknown_item_frames_and_mission_item_outside_guided_are_refused(copter: tuple[Rig, Client, int]) -> None:
    rig, c, _port = copter
    c.recv("HEARTBEAT")
    c.conn.mav.mission_item_send(1, 1, 0, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, 16, 2, 0, 0, 0, 0, 0, 47.0, 8.0, 10)
    assert "GUIDED" in c.recv("STATUSTEXT", 3.0, lambda m: "Guided" in m.text).text
    assert c.recv("MISSION_ACK").type == M.MAV_MISSION_ERROR  # not in GUIDED
    assert rig.ap.telemetry.state().mode is FlightMode.HOLD


def test_items_dropped_seq_zero_renumbered() -> None:
    from harness.autopilot.autopilot import Autopilot
    from harness.autopilot.mavlink.ardupilot.adapter import CopterSystem

    core = Autopilot()
    api = CopterSystem(core, CopterParams(core.params, 1))
    items = [MissionItem(i, 3, 16, x=1, y=1, z=5.0) for i in range(3)]
    assert api.mission.upload(items).ok
    assert [it.seq for it in core.mission.download()] == [0, 1]
    assert [it.seq for it in api.mission.download()] == [0, 1, 2]  # item 0: home again


def test_refusals_read_as_ardupilot_words() -> None:
    from harness.autopilot.api import Severity, StatusText
    from harness.autopilot.mavlink.ardupilot.adapter import copter_text

    said = copter_text(StatusText(0, Severity.CRITICAL, "Arming denied: no 3D GPS fix (fix type 1)"))
    assert said.text == "PreArm: no 3D GPS fix (fix type 1)"
    assert copter_text(StatusText(0, Severity.INFO, "Mission item 2 reached")).text == "Reached command #3"


def test_arming_refused_outside_armable_modes(copter: tuple[Rig, Client, int]) -> None:
    _rig, c, _port = copter
    c.recv("HEARTBEAT")
    assert c.mode("BRAKE").result == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_DENIED
    assert c.recv("STATUSTEXT", 3.0, lambda m: "Arm:" in m.text).text == "Arm: Mode not armable"
    assert c.mode("LOITER").result == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    assert (
        c.recv("HEARTBEAT", 3.0, lambda m: m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED).custom_mode == CopterMode.LOITER
    )


def test_sys_status_shows_the_fence_enabled_only_with_fence_enable(copter: tuple[Rig, Client, int]) -> None:
    from harness.autopilot.mavlink.telemetry import SENSOR_GEOFENCE

    _rig, c, _port = copter
    assert not c.recv("SYS_STATUS").onboard_control_sensors_enabled & SENSOR_GEOFENCE
    c.conn.mav.param_set_send(1, 1, b"FENCE_ENABLE", 1.0, M.MAV_PARAM_TYPE_INT32)
    c.recv("SYS_STATUS", 5.0, lambda m: m.onboard_control_sensors_enabled & SENSOR_GEOFENCE)


def test_tcp_clients_come_and_go(copter: tuple[Rig, Client, int]) -> None:
    rig, c, port = copter
    c.recv("HEARTBEAT")
    for _ in range(3):  # connect, talk, hang up: the link keeps serving the others and new ones
        other = Client(port)
        other.conn.mav.param_request_read_send(1, 1, b"FRAME_CLASS", -1)
        assert other.recv("PARAM_VALUE", 3.0, lambda m: m.param_id == "FRAME_CLASS").param_value == 1.0
        other.close()
    assert c.recv("HEARTBEAT").autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA
    tcp = next(lk for lk in rig.server.links if lk.name == "tcp")
    wait_until(lambda: len(tcp.destinations(0)) == 1, 3.0, "only the first client left", poll_s=0.05)


def test_streams_of_arducopters_groups_rc_imu_pressure_and_outputs(copter: tuple[Rig, Client, int]) -> None:
    """DroneKit asks for every stream at 4 Hz: the RAW_SENS and RC_CHAN groups come too."""
    _rig, c, _port = copter
    c.recv("HEARTBEAT")
    c.conn.mav.request_data_stream_send(1, 1, M.MAV_DATA_STREAM_ALL, 4, 1)
    rc = c.recv("RC_CHANNELS")
    assert rc.chancount == 16 and rc.chan3_raw == 1000  # SITL's radio: throttle low, the rest centred
    assert [rc.chan1_raw, rc.chan2_raw, rc.chan4_raw, rc.chan16_raw, rc.chan17_raw] == [1500, 1500, 1500, 1500, 0]
    assert c.recv("RC_CHANNELS_RAW").chan3_raw == 1000
    imu = c.recv("RAW_IMU")
    assert -1100 < imu.zacc < -900 and abs(imu.xacc) < 100  # mG, at rest
    assert -1100 < c.recv("SCALED_IMU2").zacc < -900
    assert 900.0 < c.recv("SCALED_PRESSURE").press_abs < 1100.0  # hPa
    assert c.recv("SERVO_OUTPUT_RAW").servo1_raw == 1000  # disarmed
    c.recv(["POWER_STATUS"])
    c.recv(["MEMINFO"])
    n = sum(1 for _ in range(40) if c.conn.recv_match(type="RAW_IMU", blocking=True, timeout=0.3) is not None)
    assert n > 0
    c.conn.mav.request_data_stream_send(1, 1, M.MAV_DATA_STREAM_RAW_SENSORS, 0, 0)  # stop the group
    time.sleep(0.5)
    while c.conn.recv_match(blocking=False) is not None:
        pass
    assert c.conn.recv_match(type="RAW_IMU", blocking=True, timeout=1.0) is None


def _override(c: Client, roll: int = 0, pitch: int = 0, thr: int = 0, yaw: int = 0) -> None:
    c.conn.mav.rc_channels_override_send(1, 1, roll, pitch, thr, yaw, 65535, 65535, 65535, 65535)


def test_rc_override_flies_alt_hold_and_times_out(copter: tuple[Rig, Client, int]) -> None:
    """ALT_HOLD on RC_CHANNELS_OVERRIDE: throttle above mid climbs, mid holds, roll right moves east; the
    channels read back; RC_OVERRIDE_TIME after the last override the radio's low throttle lands the vehicle."""
    rig, c, _port = copter
    c.recv("HEARTBEAT")
    c.conn.mav.request_data_stream_send(1, 1, M.MAV_DATA_STREAM_ALL, 10, 1)
    assert c.mode("ALT_HOLD").result == M.MAV_RESULT_ACCEPTED
    _override(c, 1500, 1500, 1100, 1500)
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    assert c.recv("RC_CHANNELS", 3.0, lambda m: m.chan3_raw == 1100).chan1_raw == 1500
    end = time.monotonic() + 40
    while rig.ap.telemetry.state().rel_alt_m < 5.0:
        assert time.monotonic() < end, "no climb on throttle 1750"
        _override(c, 1500, 1500, 1750, 1500)
        time.sleep(0.1)
    assert c.recv("HEARTBEAT").custom_mode == CopterMode.ALT_HOLD
    s0 = rig.ap.telemetry.state()
    for _ in range(20):  # mid throttle: hold the altitude; roll right
        _override(c, 1700, 1500, 1500, 1500)
        time.sleep(0.1)
    s1 = rig.ap.telemetry.state()
    assert abs(s1.rel_alt_m - s0.rel_alt_m) < 1.0 and s1.pos_ned_m[1] - s0.pos_ned_m[1] > 1.0
    c.recv("LOCAL_POSITION_NED", 3.0)
    # no more overrides: 3 s of sim time later (RC_OVERRIDE_TIME) the vehicle lands
    c.recv("RC_CHANNELS", 10.0, lambda m: m.chan3_raw == 1000)
    c.recv("HEARTBEAT", 5.0, lambda m: m.custom_mode == CopterMode.LAND)


def _attitude(c: Client, pitch_deg: float = 0.0, thrust: float = 0.5) -> None:
    q = quat_from_euler(0.0, math.radians(pitch_deg), 0.0)
    c.conn.mav.set_attitude_target_send(0, 1, 1, 0b00000100, q, 0, 0, 0, thrust)  # DroneKit's example's mask


def test_set_attitude_target_flies_guided_nogps_with_thrust_as_climb_rate(copter: tuple[Rig, Client, int]) -> None:
    """DroneKit's set_attitude_target.py: GUIDED_NOGPS, arm, thrust 0.7 climbs (GUID_OPTIONS 0: thrust is a
    climb rate, 0.5 holds the altitude), pitch -5 deg moves forward; outside GUIDED the targets are ignored."""
    rig, c, _port = copter
    c.recv("HEARTBEAT")
    _attitude(c, thrust=0.9)  # STABILIZE: ignored
    assert c.mode("GUIDED_NOGPS").result == M.MAV_RESULT_ACCEPTED
    assert c.recv("HEARTBEAT", 3.0, lambda m: m.custom_mode == CopterMode.GUIDED_NOGPS)
    assert rig.ap.telemetry.state().mode is FlightMode.HOLD
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    end = time.monotonic() + 40
    while rig.ap.telemetry.state().rel_alt_m < 2.4:
        assert time.monotonic() < end, "no climb on thrust 0.7"
        _attitude(c, thrust=0.7)
        time.sleep(0.1)
    s0 = rig.ap.telemetry.state()
    assert s0.mode is FlightMode.OFFBOARD and c.recv("HEARTBEAT").custom_mode == CopterMode.GUIDED_NOGPS
    for _ in range(15):
        _attitude(c, thrust=0.5)
        time.sleep(0.1)
    s1 = rig.ap.telemetry.state()
    assert abs(s1.rel_alt_m - s0.rel_alt_m) < 0.8  # held (the climb brakes within it)
    for _ in range(15):
        _attitude(c, pitch_deg=-5.0, thrust=0.5)
        time.sleep(0.1)
    s2 = rig.ap.telemetry.state()
    fwd = (s2.pos_ned_m[0] - s1.pos_ned_m[0]) * math.cos(s1.yaw_rad) + (s2.pos_ned_m[1] - s1.pos_ned_m[1]) * math.sin(
        s1.yaw_rad
    )
    assert fwd > 1.0 and abs(s2.rel_alt_m - s1.rel_alt_m) < 1.0
    assert c.mode("LAND").result == M.MAV_RESULT_ACCEPTED


def test_do_change_speed_takes_arducopters_limits(copter: tuple[Rig, Client, int]) -> None:
    _rig, c, _port = copter
    c.recv("HEARTBEAT")
    assert c.command(M.MAV_CMD_DO_CHANGE_SPEED, 1, 15).result == M.MAV_RESULT_ACCEPTED  # beyond PX4's 12 m/s
    assert c.command(M.MAV_CMD_DO_CHANGE_SPEED, 2, 4).result == M.MAV_RESULT_ACCEPTED  # climb speed
    assert c.command(M.MAV_CMD_DO_CHANGE_SPEED, 1, 0).result == M.MAV_RESULT_FAILED


def test_reboot_restarts_the_flight_stack_in_place(copter: tuple[Rig, Client, int]) -> None:
    rig, c, _port = copter
    c.recv("HEARTBEAT")
    assert c.mode("GUIDED").result == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1).result == M.MAV_RESULT_FAILED  # armed
    assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0).result == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 0).result == M.MAV_RESULT_UNSUPPORTED
    assert c.command(M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1).result == M.MAV_RESULT_ACCEPTED
    assert c.recv("STATUSTEXT", 5.0, lambda m: m.text.startswith("ArduCopter V4.5.7"))
    hb = c.recv("HEARTBEAT", 3.0)
    assert hb.custom_mode == CopterMode.STABILIZE and not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert rig.ap.telemetry.state().home is None or rig.ap.telemetry.state().t_ns > 0
    # the new estimator converges and the vehicle arms again
    c.recv("HEARTBEAT", 3.0)
    assert c.mode("GUIDED").result == M.MAV_RESULT_ACCEPTED
    end = time.monotonic() + 30
    while c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result != M.MAV_RESULT_ACCEPTED:
        assert time.monotonic() < end, "not armable after the reboot"
        time.sleep(0.5)


@pytest.mark.parametrize(
    ("frame", "cmd", "lat", "alt", "result"),
    [
        (200, 16, 47.0, 10.0, M.MAV_MISSION_UNSUPPORTED_FRAME),
        (M.MAV_FRAME_LOCAL_NED, 16, 47.0, 10.0, M.MAV_MISSION_UNSUPPORTED_FRAME),
        (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, 31000, 47.0, 10.0, M.MAV_MISSION_UNSUPPORTED),
        (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, 16, 95.0, 10.0, M.MAV_MISSION_INVALID_PARAM5_X),
        (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, 16, 47.0, 90_000.0, M.MAV_MISSION_INVALID_PARAM7),
    ],
    ids=["frame-200", "local-ned", "unknown-command", "latitude-95", "altitude-90km"],
)
def test_items_ardupilot_refuses_are_refused_with_its_result(
    copter: tuple[Rig, Client, int], frame: int, cmd: int, lat: float, alt: float, result: int
) -> None:
    """Issue 36, item 2, ArduCopter (``AP_Mission::mavlink_int_to_mission_cmd``): the item's frame, command and
    location are checked as it arrives; the upload ends with ArduPilot's MAV_MISSION_RESULT, nothing taken in."""
    rig, c, _port = copter
    c.recv("HEARTBEAT")
    c.conn.waypoint_count_send(2)
    items = [(M.MAV_FRAME_GLOBAL, 16, 47.0, 0.0), (frame, cmd, lat, alt)]  # item 0: home, ignored
    while True:
        m = c.recv(["MISSION_REQUEST", "MISSION_ACK"])
        if m.get_type() == "MISSION_ACK":
            break
        f, command, x, z = items[m.seq]
        c.conn.mav.mission_item_send(1, 1, m.seq, f, command, 0, 1, 0, 0, 0, 0, x, 8.0, z)
    assert m.type == result
    assert rig.ap.mission.download() == ()
