"""PX4 services over a real UDP socket: the tlog keeps every frame (known dialect or not), HIGHRES_IMU carries
the magnetometer exactly when SYS_STATUS calls it healthy, failure injection is gated by SYS_FAILURE_EN, and
the MAVLink log protocol downloads the vehicle's ULog byte for byte."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as M

from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.autopilot.mavlink.transport import PortsConfig
from harness.autopilot.sitl import attach_mavlink
from tests.autopilot.mavlink.conftest import Gcs
from tests.autopilot.quadsim import QuadSim

pyulog = pytest.importorskip("pyulog")

MAG = M.MAV_SYS_STATUS_SENSOR_3D_MAG
MAG_FIELDS = 0x1C0


def _raw_frame(msg_id: int, payload: bytes, seq: int = 0) -> bytes:
    """A MAVLink 2 frame of a message this dialect does not know (CRC over an arbitrary CRC_EXTRA)."""
    from pymavlink.generator.mavcrc import x25crc

    header = bytes([0xFD, len(payload), 0, 0, seq, 245, 190]) + msg_id.to_bytes(3, "little")
    crc = x25crc(header[1:] + payload)
    crc.accumulate(bytes([0]))
    return header + payload + struct.pack("<H", crc.crc)


class _Vehicle:
    def __init__(self, gcs: Gcs, run_dir: Path) -> None:
        self.sim = QuadSim(np.random.default_rng(3))
        self.ap = Autopilot(AutopilotConfig())
        self.frame = self.sim.frame()
        self.attached = attach_mavlink(self.ap, PortsConfig(api_port_base=gcs.port, gcs_port=0), run_dir, None)

    def step_s(self, seconds: float) -> None:
        for _ in range(round(seconds * 1e9 / self.sim.tick_ns)):
            self.frame = self.sim.step(self.ap.step(self.frame))


def test_tlog_imu_mag_failure_injection_and_log_download(gcs: Gcs, tmp_path: Path) -> None:
    v = _Vehicle(gcs, tmp_path)
    try:
        v.step_s(12.0)
        gcs.connect()
        # a frame outside the common dialect (PLAY_TUNE_V2, id 400) goes into the tlog as it came
        tune = _raw_frame(400, bytes([1, 1]) + struct.pack("<I", 1) + b"MFT240L8 O4aO5dc O4aO5dc")
        gcs.send_raw(tune)
        # HIGHRES_IMU: magnetometer fields present and flagged, as SYS_STATUS says the mag is healthy
        assert gcs.command(512, M.MAVLINK_MSG_ID_HIGHRES_IMU).result == M.MAV_RESULT_ACCEPTED
        imu = gcs.recv("HIGHRES_IMU")
        status = gcs.recv("SYS_STATUS")
        assert status.onboard_control_sensors_health & MAG
        assert imu.fields_updated & MAG_FIELDS == MAG_FIELDS and 0.1 < np.hypot(imu.xmag, imu.ymag) < 1.0
        assert imu.abs_pressure == pytest.approx(950.0, abs=50.0)  # hPa at 488 m
        # failure injection: DENIED until SYS_FAILURE_EN, then the mag is off and both messages say so
        assert gcs.command(420, 2, 1, 0).result == M.MAV_RESULT_DENIED
        gcs.send(gcs.mav.param_set_encode(1, 1, b"SYS_FAILURE_EN", struct.unpack("<f", struct.pack("<i", 1))[0], 6))
        gcs.recv("PARAM_VALUE", cond=lambda m: m.param_id == "SYS_FAILURE_EN")
        assert gcs.command(420, 2, 1, 0).result == M.MAV_RESULT_ACCEPTED
        assert gcs.command(420, 8, 1, 0).result == M.MAV_RESULT_UNSUPPORTED  # airspeed: not simulated
        v.step_s(3.0)
        assert gcs.command(512, M.MAVLINK_MSG_ID_HIGHRES_IMU).result == M.MAV_RESULT_ACCEPTED
        assert gcs.recv("HIGHRES_IMU").fields_updated & MAG_FIELDS == 0
        assert not gcs.recv("SYS_STATUS").onboard_control_sensors_health & MAG
        # the log protocol: one log, downloaded in full, identical to the file, a ULog pyulog reads
        gcs.send(gcs.mav.log_request_list_encode(1, 1, 0, 0xFFFF))
        entry = gcs.recv("LOG_ENTRY")
        assert entry.id == 0 and entry.num_logs == 1 and entry.last_log_num == 0 and entry.size > 10_000
        data = bytearray(entry.size)
        got = 0
        for ofs in range(0, entry.size, 90 * 200):
            gcs.send(gcs.mav.log_request_data_encode(1, 1, 0, ofs, 90 * 200))
            for _, m in gcs.collect(0.5, {"LOG_DATA"}):
                data[m.ofs : m.ofs + m.count] = bytes(m.data[: m.count])
                got += m.count
        assert got == entry.size
        gcs.send(gcs.mav.log_request_data_encode(1, 1, 0, entry.size, 90))
        assert gcs.recv("LOG_DATA").count == 0  # past the end
        gcs.send(gcs.mav.log_request_end_encode(1, 1))
        assert bytes(data) == (tmp_path / "vehicle-0.ulg").read_bytes()[: entry.size]
        (tmp_path / "down.ulg").write_bytes(data)
        log = pyulog.ULog(str(tmp_path / "down.ulg"))
        names = {d.name for d in log.data_list}
        assert {"vehicle_local_position", "vehicle_attitude", "sensor_combined", "battery_status"} <= names
        assert "vehicle_status" in names
        ts = log.get_dataset("vehicle_attitude").data["timestamp"]
        assert ts[0] < 100_000 and 12_000_000 < ts[-1] < 16_000_000  # µs of sim time
        assert any("mag" in m.message for m in log.logged_messages)
    finally:
        v.attached.close()
    assert tune in (tmp_path / "vehicle-0.tlog").read_bytes()
