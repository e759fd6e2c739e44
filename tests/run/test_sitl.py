"""`harness sitl`: a ground station on the GCS port sees every vehicle and downloads all parameters."""

from __future__ import annotations

import json
import signal
import subprocess
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from .flights import start_sitl, start_sitl_ports

pytestmark = pytest.mark.sim


def test_ground_station_sees_every_vehicle_and_its_parameters(tmp_path: Path) -> None:
    proc, port = start_sitl(2, tmp_path / "sitl")
    try:
        gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
        seen: dict[int, int] = {}
        end = time.monotonic() + 20
        while len(seen) < 2 and time.monotonic() < end:
            hb = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=1)
            if hb is not None:
                seen[hb.get_srcSystem()] = hb.autopilot
        assert seen == {1: mavutil.mavlink.MAV_AUTOPILOT_PX4, 2: mavutil.mavlink.MAV_AUTOPILOT_PX4}
        gcs.mav.param_request_list_send(2, 1)
        indices: set[int] = set()
        count = None
        end = time.monotonic() + 30
        while (count is None or len(indices) < count) and time.monotonic() < end:
            p = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=1)
            if p is not None and p.get_srcSystem() == 2:
                count = p.param_count
                indices.add(p.param_index)
            elif p is None and count is not None:  # like QGroundControl: ask again for what UDP lost
                for missing in sorted(set(range(count)) - indices):
                    gcs.mav.param_request_read_send(2, 1, b"", missing)
        assert count is not None and count > 50 and indices == set(range(count))
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=10)
    assert json.loads((tmp_path / "sitl" / "summary.json").read_text())["status"] == "interrupted"
    assert proc.returncode == 0


def test_a_second_ctrl_c_to_harness_sitl_ends_it_as_the_first_does(tmp_path: Path) -> None:
    """Issue 36, item 7: two SIGINTs 0.2 s apart ended ``harness sitl`` in a ``StopSignal: 2`` traceback, exit 1
    (2 of 2 tries). Now the second is part of the same stop: the exit code of one Ctrl-C, no traceback."""
    codes = []
    for signals in (1, 2, 2):
        proc, gcs_port, _api = start_sitl_ports(1, tmp_path / f"sitl{len(codes)}", subprocess.DEVNULL)
        try:
            conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}")
            assert conn.wait_heartbeat(timeout=30) is not None
            conn.close()
            for _ in range(signals):
                proc.send_signal(signal.SIGINT)
                time.sleep(0.2)
            _out, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        assert "Traceback" not in err and "StopSignal" not in err, err[-2000:]
        codes.append(proc.returncode)
    assert codes == [0, 0, 0], codes


def test_harness_sitl_starts_on_a_run_directory_whose_parameter_file_is_hostile(tmp_path: Path) -> None:
    """Issue 36, item 4: a ``parameters.json`` written over MAVFTP with a 401-digit number made the next
    ``harness sitl`` on that ``--out`` fail ("internal error: OverflowError"). Now it starts; the value is ignored
    in one line, the good one is taken."""
    out = tmp_path / "sitl"
    (out / "params").mkdir(parents=True)
    (out / "params" / "vehicle-0.json").write_text('{"MPC_XY_VEL_MAX": 1' + "0" * 400 + ', "MPC_XY_CRUISE": 7.0}')
    proc, gcs_port, _api = start_sitl_ports(1, out, subprocess.DEVNULL)
    try:
        conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=254)
        assert conn.wait_heartbeat(timeout=30) is not None
        conn.mav.param_request_read_send(1, 1, b"MPC_XY_CRUISE", -1)
        value = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=10)
        assert value is not None and value.param_id == "MPC_XY_CRUISE" and value.param_value == 7.0
        conn.close()
    finally:
        proc.send_signal(signal.SIGINT)
        _out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0 and "Traceback" not in err, err[-2000:]
    warned = [line for line in err.splitlines() if "vehicle-0.json" in line]
    assert len(warned) == 1 and "not finite numbers: 'MPC_XY_VEL_MAX'" in warned[0], err[-2000:]
