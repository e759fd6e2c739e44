"""A survey as photogrammetry users fly it on PX4 SITL (test data for ``test_camera.py``), in pymavlink: ask the
camera component (100) for its CAMERA_INFORMATION, upload takeoff, DO_SET_CAM_TRIGG_DIST N, two legs (100 m north, 65 m east),
DO_SET_CAM_TRIGG_DIST 0 and return, fly it, and print every CAMERA_IMAGE_CAPTURED as a JSON line."""

from __future__ import annotations

import json
import math
import os
import sys
import time

os.environ["MAVLINK20"] = "1"  # the camera messages are MAVLink 2's (pymavlink's default dialect is 1.0's)

from pymavlink import mavutil

M = mavutil.mavlink
DIST_M = float(sys.argv[1]) if len(sys.argv) > 1 else 10.0


def main() -> None:
    m = mavutil.mavlink_connection("udpin:0.0.0.0:14540", source_system=245)
    m.wait_heartbeat(timeout=30)
    sysid = m.target_system
    m.mav.command_long_send(
        sysid, 100, M.MAV_CMD_REQUEST_MESSAGE, 0, M.MAVLINK_MSG_ID_CAMERA_INFORMATION, 0, 0, 0, 0, 0, 0
    )
    info = m.recv_match(type="CAMERA_INFORMATION", blocking=True, timeout=10)
    print(f"CAMERA {info.get_srcComponent()} {bytes(info.model_name).rstrip(bytes(1)).decode()}", flush=True)
    pos = None
    while pos is None or pos.lat == 0:
        pos = m.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=10)
    lat0, lon0 = pos.lat / 1e7, pos.lon / 1e7

    def at(north: float, east: float) -> tuple[int, int]:
        dlat = north / 6_378_137.0
        dlon = east / (6_378_137.0 * math.cos(math.radians(lat0)))
        return round((lat0 + math.degrees(dlat)) * 1e7), round((lon0 + math.degrees(dlon)) * 1e7)

    items = [
        (M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, *at(0, 0), 20.0),
        (M.MAV_CMD_DO_SET_CAM_TRIGG_DIST, DIST_M, 0, 1, 0, 0, 0.0),
        (M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, *at(100, 0), 20.0),
        (M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, *at(100, 65), 20.0),
        (M.MAV_CMD_DO_SET_CAM_TRIGG_DIST, 0, 0, 0, 0, 0, 0.0),
        (M.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0.0),
    ]
    m.mav.mission_count_send(sysid, 1, len(items), 0)
    while True:
        req = m.recv_match(type=["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"], blocking=True, timeout=10)
        if req is None or req.get_type() == "MISSION_ACK":
            break
        cmd, p1, p2, p3, x, y, z = items[req.seq]
        # as QGroundControl and MAVSDK send them (and PX4 takes them only so): items with a position in a global
        # frame, the others in MAV_FRAME_MISSION
        positioned = cmd in (M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_WAYPOINT)
        frame = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT if positioned else M.MAV_FRAME_MISSION
        m.mav.mission_item_int_send(sysid, 1, req.seq, frame, cmd, 0, 1, p1, p2, p3, 0, x, y, z, 0)
    print(f"UPLOAD {req.type if req is not None else 'timeout'}", flush=True)
    while not m.motors_armed():
        m.mav.command_long_send(sysid, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        m.recv_match(type="HEARTBEAT", blocking=True, timeout=1)
    m.mav.command_long_send(sysid, 1, M.MAV_CMD_MISSION_START, 0, 0, 0, 0, 0, 0, 0, 0)
    deadline = time.monotonic() + 300
    armed_seen = True
    while time.monotonic() < deadline:
        msg = m.recv_match(type=["CAMERA_IMAGE_CAPTURED", "HEARTBEAT", "CAMERA_TRIGGER"], blocking=True, timeout=1)
        if msg is None:
            continue
        if msg.get_type() == "CAMERA_IMAGE_CAPTURED":
            d = {k: getattr(msg, k) for k in ("time_boot_ms", "lat", "lon", "alt", "relative_alt", "image_index")}
            d.update(q=list(msg.q), file_url=msg.file_url, compid=msg.get_srcComponent())
            print("CAPTURED " + json.dumps(d), flush=True)
        elif msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == 1:
            armed = bool(msg.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
            if armed_seen and not armed:
                break
            armed_seen = armed
    print("DONE", flush=True)


if __name__ == "__main__":
    main()
