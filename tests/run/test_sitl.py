"""`harness sitl`: a ground station on the GCS port sees every vehicle and downloads all parameters."""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from .flights import start_sitl

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
