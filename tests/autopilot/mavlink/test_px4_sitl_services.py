"""PX4 SITL's own services over a real UDP socket, driven as pymavlink would drive them: calibration with the
``[cal]`` texts MAVSDK parses, the gimbal manager (v2), MAVFTP over the vehicle's file tree (a ULog
downloaded byte for byte), the MAVLink shell, reboot, and the full PX4 parameter table."""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as M

from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.autopilot.mavlink.ftp import crc32_px4
from harness.autopilot.mavlink.transport import PortsConfig
from harness.autopilot.params import PARAM_DEFS
from harness.autopilot.sitl import attach_mavlink
from harness.core.clock import real_sleep
from tests.autopilot.mavlink.conftest import Gcs
from tests.autopilot.quadsim import QuadSim

_FTP = struct.Struct("<HBBBBBBI")


class _Vehicle:
    def __init__(self, gcs: Gcs, run_dir: Path) -> None:
        self.sim = QuadSim(np.random.default_rng(3))
        self.ap = Autopilot(AutopilotConfig(params={"MIS_TAKEOFF_ALT": 3.0}))
        self.frame = self.sim.frame()
        self.attached = attach_mavlink(self.ap, PortsConfig(api_port_base=gcs.port, gcs_port=0), run_dir, None)

    def step_s(self, seconds: float) -> None:
        for _ in range(round(seconds * 1e9 / self.sim.tick_ns)):
            self.frame = self.sim.step(self.ap.step(self.frame))


@pytest.fixture
def vehicle(gcs: Gcs, tmp_path: Path) -> _Vehicle:
    v = _Vehicle(gcs, tmp_path)
    v.step_s(12.0)
    gcs.connect()
    yield v
    v.attached.close()


def _texts(gcs: Gcs, seconds: float = 0.5) -> list[str]:
    return [m.text for _, m in gcs.collect(seconds, {"STATUSTEXT"})]


def test_calibrations_report_as_px4_and_store_results(gcs: Gcs, vehicle: _Vehicle) -> None:
    for params, kind, seconds in (
        ((1, 0, 0, 0, 0), "gyro", 2.5),
        ((0, 0, 0, 0, 1), "accel", 6.5),
        ((0, 1, 0, 0, 0), "mag", 6.5),
        ((0, 0, 0, 0, 2), "level", 2.5),
    ):
        assert gcs.command(241, *params).result == M.MAV_RESULT_ACCEPTED
        vehicle.step_s(seconds)
        texts = _texts(gcs)
        assert texts[0] == f"[cal] calibration started: 2 {kind}", texts
        assert texts[-1] == f"[cal] calibration done: {kind}", texts
        assert all(t.startswith("[cal] ") for t in texts)
        if kind in ("gyro", "level"):
            assert [t for t in texts if "progress" in t] == [f"[cal] progress <{p}>" for p in range(10, 101, 10)]
        else:
            for side in ("down", "up", "left", "right", "front", "back"):
                assert f"[cal] {side} orientation detected" in texts
                assert f"[cal] {side} side done, rotate to a different side" in texts
    ap = vehicle.ap
    assert ap.params.get("CAL_GYRO0_ID") == 1310988 and ap.params.get("CAL_ACC0_ID") == 1310988
    assert ap.params.get("CAL_MAG0_ID") == 197388
    assert abs(ap.params.get("CAL_GYRO0_XOFF")) < 0.05 and abs(ap.params.get("CAL_ACC0_ZOFF")) < 0.5
    assert abs(ap.params.get("SENS_BOARD_X_OFF")) < 3 and abs(ap.params.get("SENS_BOARD_Y_OFF")) < 3
    # cancel, unsupported kinds, refusal while armed
    assert gcs.command(241, 1).result == M.MAV_RESULT_ACCEPTED
    assert gcs.command(241, 0, 0, 0, 0, 0, 0, 0).result == M.MAV_RESULT_ACCEPTED
    vehicle.step_s(0.5)
    assert "[cal] calibration cancelled" in _texts(gcs)
    assert gcs.command(241, 0, 0, 1).result == M.MAV_RESULT_UNSUPPORTED  # baro
    assert gcs.command(400, 1).result == M.MAV_RESULT_ACCEPTED
    vehicle.step_s(0.1)
    assert gcs.command(241, 1).result == M.MAV_RESULT_DENIED


def _last_attitude(gcs: Gcs) -> object:
    return gcs.collect(0.3, {"GIMBAL_DEVICE_ATTITUDE_STATUS"})[-1][1]


def test_gimbal_manager_discovery_control_and_attitude(gcs: Gcs, vehicle: _Vehicle) -> None:
    vehicle.step_s(1.0)
    assert not gcs.collect(0.3, {"GIMBAL_DEVICE_ATTITUDE_STATUS"})  # nobody used the gimbal yet: not streamed
    assert gcs.command(512, M.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION).result == M.MAV_RESULT_ACCEPTED
    info = gcs.recv("GIMBAL_MANAGER_INFORMATION")
    assert info.gimbal_device_id == 1 and info.pitch_min == pytest.approx(-np.pi / 2)
    assert gcs.command(512, M.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION).result == M.MAV_RESULT_ACCEPTED
    assert gcs.recv("GIMBAL_DEVICE_INFORMATION").gimbal_device_id == 1
    gcs.send(gcs.mav.command_long_encode(1, 1, 1001, 0, -1, -1, -2, -2, 0, 0, 1))  # take primary control
    assert gcs.recv("COMMAND_ACK", cond=lambda m: m.command == 1001).result == M.MAV_RESULT_ACCEPTED
    status = gcs.recv("GIMBAL_MANAGER_STATUS")
    assert (status.primary_control_sysid, status.primary_control_compid) == (245, 190)
    assert gcs.command(1000, -60, 30, np.nan, np.nan, 0, 0, 1).result == M.MAV_RESULT_ACCEPTED
    vehicle.step_s(2.0)
    att = _last_attitude(gcs)
    w, x, y, z = att.q
    pitch = np.degrees(np.arcsin(np.clip(2 * (w * y - z * x), -1, 1)))
    yaw = np.degrees(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
    assert pitch == pytest.approx(-60, abs=1.0) and yaw == pytest.approx(30, abs=1.0)
    assert att.flags & M.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
    # rates: 10 deg/s up for 2 s from -60
    gcs.send(gcs.mav.gimbal_manager_set_attitude_encode(1, 1, 0, 1, [np.nan] * 4, 0, np.radians(10), 0))
    real_sleep(0.2)  # handled (by the server's thread) before the vehicle moves on
    vehicle.step_s(2.0)
    w, x, y, z = _last_attitude(gcs).q
    assert np.degrees(np.arcsin(2 * (w * y - z * x))) == pytest.approx(-40, abs=2.5)
    # someone else cannot move it while we hold control
    other = Gcs(sysid=200)
    other.server = gcs.server
    try:
        other.send(other.mav.gimbal_manager_set_pitchyaw_encode(1, 1, 0, 1, 0.0, 0.0, np.nan, np.nan))
    finally:
        other.close()
    vehicle.step_s(1.0)
    w, x, y, z = _last_attitude(gcs).q
    assert np.degrees(np.arcsin(2 * (w * y - z * x))) < -30
    gcs.send(gcs.mav.command_long_encode(1, 1, 1001, 0, -3, -3, -3, -3, 0, 0, 1))  # release
    assert gcs.recv("COMMAND_ACK", cond=lambda m: m.command == 1001).result == M.MAV_RESULT_ACCEPTED
    assert gcs.recv("GIMBAL_MANAGER_STATUS").primary_control_sysid == 0
    tlog = (vehicle.ap.flight_log.path.parent / "vehicle-0.tlog").read_bytes()  # type: ignore[union-attr]
    assert bytes([0xFD]) in tlog and (285).to_bytes(3, "little") in tlog  # the attitude is in the tlog


class _Ftp:
    def __init__(self, gcs: Gcs) -> None:
        self.gcs = gcs
        self.seq = 0

    def request(
        self, op: int, path: bytes = b"", session: int = 0, offset: int = 0, size: int | None = None, many: bool = False
    ) -> list[tuple[tuple[int, ...], bytes]]:
        self.seq += 1
        body = path
        header = _FTP.pack(self.seq, session, op, len(body) if size is None else size, 0, 0, 0, offset)
        payload = header + body
        gcs = self.gcs
        gcs.send(gcs.mav.file_transfer_protocol_encode(0, 1, 1, list(payload) + [0] * (251 - len(payload))))
        out = []
        for _, m in gcs.collect(0.3 if many else 0.2, {"FILE_TRANSFER_PROTOCOL"}):
            raw = bytes(m.payload)
            h = _FTP.unpack_from(raw)
            out.append((h, raw[12 : 12 + h[3]]))
        assert out, f"no answer to opcode {op}"
        return out

    def one(self, op: int, path: bytes = b"", **kw: int) -> tuple[tuple[int, ...], bytes]:
        (h, data), *_ = self.request(op, path, **kw)
        assert h[0] == (self.seq + 1) & 0xFFFF
        return h, data

    def ls(self, path: bytes) -> list[str]:
        entries: list[str] = []
        while True:
            h, data = self.one(3, path + b"\0", offset=len(entries))
            if h[2] == 129:
                assert data[0] == 6, data  # EOF
                return entries
            entries += [e.decode() for e in data.split(b"\0") if e]


def test_mavftp_lists_walks_downloads_writes(gcs: Gcs, vehicle: _Vehicle, tmp_path: Path) -> None:
    ftp = _Ftp(gcs)
    root = ftp.ls(b"/")
    assert {"Detc", "Dlog"} <= set(root) and any(e.startswith("Fparameters.json\t") for e in root)
    days = ftp.ls(b"/log")
    assert len(days) == 1 and days[0].startswith("D")
    logs = ftp.ls(b"/log/" + days[0][1:].encode())
    assert len(logs) == 1 and logs[0].endswith(".ulg\t" + logs[0].split("\t")[1])
    assert int(logs[0].split("\t")[1]) > 10_000  # the log's size up to its last whole message (flushed)
    path = b"/log/" + days[0][1:].encode() + b"/" + logs[0][1:].split("\t")[0].encode()
    # open, burst-read to the end (a burst is at most 100 ACKs; ask again from where it stopped), terminate
    h, data = ftp.one(4, path + b"\0")
    assert h[2] == 128
    session, size = h[1], struct.unpack("<I", data[:4])[0]
    got = bytearray()
    while len(got) < size:
        replies = ftp.request(15, session=session, offset=len(got), size=239, many=True)
        for (_seq, _s, op, n, req, _done, _pad, offset), body in replies:
            assert op == 128 and req == 15 and offset == len(got)
            got += body[:n]
    h, data = ftp.one(15, session=session, offset=size, size=239)
    assert h[2] == 129 and data[0] == 6  # past the end: EOF
    assert ftp.one(1, session=session)[0][2] == 128
    assert bytes(got) == (tmp_path / "vehicle-0.ulg").read_bytes()[:size] and size > 10_000
    # write a file, read it back, its CRC, rename, truncate, remove; directories
    assert ftp.one(9, b"/etc/mine\0")[0][2] == 128
    h, _ = ftp.one(6, b"/etc/mine/a.txt\0")
    assert h[2] == 128
    s = h[1]
    content = b"hello from the ground " * 20
    for ofs in range(0, len(content), 200):
        assert ftp.one(7, content[ofs : ofs + 200], session=s, offset=ofs)[0][2] == 128
    ftp.one(1, session=s)
    assert (tmp_path / "fs/vehicle-0/etc/mine/a.txt").read_bytes() == content
    h, data = ftp.one(14, b"/etc/mine/a.txt\0")
    assert struct.unpack("<I", data[:4])[0] == crc32_px4(content)
    assert ftp.one(13, b"/etc/mine/a.txt\0/etc/mine/b.txt\0")[0][2] == 128
    assert ftp.one(12, b"/etc/mine/b.txt\0", offset=5)[0][2] == 128
    h, data = ftp.one(4, b"/etc/mine/b.txt\0")
    assert struct.unpack("<I", data[:4])[0] == 5
    assert ftp.one(5, session=h[1], offset=0, size=239)[1] == b"hello"
    ftp.one(1, session=h[1])
    assert ftp.one(10, b"/etc/mine\0")[0][2] == 129  # not empty
    assert ftp.one(8, b"/etc/mine/b.txt\0")[0][2] == 128
    assert ftp.one(10, b"/etc/mine\0")[0][2] == 128
    # nothing outside the tree; the ULog cannot be written; unknown opcode, missing file
    h, data = ftp.one(4, b"/../../../etc/passwd\0")
    assert h[2] == 129 and data[0] == 10
    h, data = ftp.one(6, path + b"\0")
    assert h[2] == 129 and data[0] == 9
    assert ftp.one(16, b"/\0")[1][0] == 7
    assert ftp.one(4, b"/nope\0")[1][0] == 10


def _fds_open_on(path: Path) -> list[Path]:
    found = []
    for fd in Path("/proc/self/fd").iterdir():
        try:
            if os.readlink(fd) == str(path):
                found.append(fd)
        except OSError:  # closed meanwhile (the directory's own fd, another thread's)
            continue
    return found


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc to see open files")
def test_stopping_a_vehicle_closes_the_files_mavftp_sessions_left_open(
    gcs: Gcs, vehicle: _Vehicle, tmp_path: Path
) -> None:
    """A ground station that vanishes mid-transfer never sends TERMINATE_SESSION: the vehicle's stop closes the file."""
    ftp = _Ftp(gcs)
    assert ftp.one(6, b"/etc/left-open.txt\0")[0][2] == 128  # CREATE_FILE: a write session, never terminated
    target = (tmp_path / "fs/vehicle-0/etc/left-open.txt").resolve()
    assert len(_fds_open_on(target)) == 1
    vehicle.attached.close()
    assert _fds_open_on(target) == []


def _shell(gcs: Gcs, line: str, vehicle: _Vehicle | None = None) -> str:
    data = line.encode()
    gcs.send(gcs.mav.serial_control_encode(10, 2 | 4, 0, 0, len(data), list(data.ljust(70, b"\0"))))
    if vehicle is not None:
        vehicle.step_s(0.2)
    out = b""
    for _, m in gcs.collect(0.3, {"SERIAL_CONTROL"}):
        assert m.device == 10 and m.flags & 1
        out += bytes(m.data[: m.count])
    return out.decode()


def test_shell_runs_commands_with_the_nsh_prompt(gcs: Gcs, vehicle: _Vehicle) -> None:
    out = _shell(gcs, "\n")
    assert "NuttShell (NSH)" in out and out.endswith("nsh> ")
    out = _shell(gcs, "param set MIS_TAKEOFF_ALT 5\n")
    assert "MIS_TAKEOFF_ALT: curr: 3.0000 -> new: 5.0000" in out and out.endswith("nsh> ")
    assert vehicle.ap.params.get("MIS_TAKEOFF_ALT") == 5.0
    assert "x + MIS_TAKEOFF_ALT" in _shell(gcs, "param show MIS_TAKEOFF*\n")
    assert "ERROR: Parameter NOPE not found." in _shell(gcs, "param set NOPE 1\n")
    ver = _shell(gcs, "ver all\n")
    assert "FW version: 1.15.0" in ver and "HW arch" in ver
    assert "q: [" in _shell(gcs, "listener vehicle_attitude\n")
    assert "nsh: frobnicate: command not found" in _shell(gcs, "frobnicate\n")
    _shell(gcs, "commander arm\n", vehicle)
    assert vehicle.ap.telemetry.state().armed
    _shell(gcs, "commander takeoff\n", vehicle)
    vehicle.step_s(6.0)
    assert vehicle.ap.telemetry.state().rel_alt_m == pytest.approx(5.0, abs=0.7)
    assert "armed: True" in _shell(gcs, "commander status\n")
    _shell(gcs, "commander land\n", vehicle)


def test_reboot_restarts_the_stack_with_the_saved_parameters(gcs: Gcs, vehicle: _Vehicle, tmp_path: Path) -> None:
    assert vehicle.ap.telemetry.state().home is not None
    gcs.send(gcs.mav.param_set_encode(1, 1, b"MPC_XY_CRUISE", 7.0, M.MAV_PARAM_TYPE_REAL32))
    gcs.recv("PARAM_VALUE", cond=lambda m: m.param_id == "MPC_XY_CRUISE")
    saved = tmp_path / "params/vehicle-0.json"
    values = json.loads(saved.read_text())
    assert values["MPC_XY_CRUISE"] == 7.0
    saved.write_text(json.dumps(values | {"MPC_XY_CRUISE": 9.0}))  # as a ground station would over MAVFTP
    assert gcs.command(246, 1).result == M.MAV_RESULT_ACCEPTED
    assert vehicle.ap.params.get("MPC_XY_CRUISE") == 9.0 and vehicle.ap.params.get("MIS_TAKEOFF_ALT") == 3.0
    assert vehicle.ap.telemetry.state().home is None
    gcs.recv("HEARTBEAT")
    vehicle.step_s(12.0)
    assert vehicle.ap.telemetry.state().home is not None and vehicle.ap.telemetry.arming_check() == ""
    assert gcs.command(246, 3).result == M.MAV_RESULT_UNSUPPORTED
    assert gcs.command(400, 1).result == M.MAV_RESULT_ACCEPTED
    vehicle.step_s(0.1)
    assert gcs.command(246, 1).result == M.MAV_RESULT_DENIED
    assert any("Reboot denied: disarm first" in t for t in _texts(gcs, 0.3))


def test_every_px4_parameter_reads_and_sets(gcs: Gcs, vehicle: _Vehicle) -> None:
    for name, value, ptype in (
        (b"EKF2_HGT_REF", 2, M.MAV_PARAM_TYPE_INT32),
        (b"LNDMC_Z_VEL_MAX", 0.4, M.MAV_PARAM_TYPE_REAL32),
    ):
        raw = struct.unpack("<f", struct.pack("<i", value))[0] if ptype == M.MAV_PARAM_TYPE_INT32 else value
        gcs.send(gcs.mav.param_set_encode(1, 1, name, raw, ptype))
        echo = gcs.recv("PARAM_VALUE", cond=lambda m, n=name: m.param_id == n.decode())
        assert echo.param_count == len(PARAM_DEFS) and echo.param_type == ptype
        assert vehicle.ap.params.get(name.decode()) == pytest.approx(value)
    # out of range: refused, the echo keeps the old value
    gcs.send(gcs.mav.param_set_encode(1, 1, b"LNDMC_Z_VEL_MAX", -1.0, M.MAV_PARAM_TYPE_REAL32))
    assert gcs.recv("PARAM_VALUE", cond=lambda m: m.param_id == "LNDMC_Z_VEL_MAX").param_value == pytest.approx(0.4)
    assert len(PARAM_DEFS) > 1400
