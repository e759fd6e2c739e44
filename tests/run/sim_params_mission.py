"""A pymavlink script as ArduPilot SITL users write them (test data for ``test_sim_params.py``): GUIDED hover at
10 m over SERIAL0, then the simulated world changed through ``SIM_*`` parameters, as MAVProxy's ``param set``
or an autotest does: wind from the west at 10 m/s, then the GPS switched off. It prints what it saw."""

from __future__ import annotations

import sys
import time

from pymavlink import mavutil

LAND = 9
GUIDED = 4


def main() -> None:
    m = mavutil.mavlink_connection("tcp:127.0.0.1:5760", source_system=255)
    m.wait_heartbeat(timeout=30)
    m.mav.request_data_stream_send(m.target_system, m.target_component, mavutil.mavlink.MAV_DATA_STREAM_ALL, 10, 1)

    def param_set(name: str, value: float) -> float:
        m.mav.param_set_send(
            m.target_system, m.target_component, name.encode(), value, mavutil.mavlink.MAV_PARAM_TYPE_REAL32
        )
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            msg = m.recv_match(type="PARAM_VALUE", blocking=True, timeout=1)
            if msg is not None and msg.param_id == name:
                print(f"PARAM_VALUE {name} {msg.param_value:g}", flush=True)
                return float(msg.param_value)
        print(f"NO PARAM_VALUE {name}", flush=True)
        sys.exit(3)

    def boot_s() -> float:
        msg = m.recv_match(type="SYSTEM_TIME", blocking=True, timeout=5)
        return msg.time_boot_ms / 1000 if msg is not None else -1.0

    print(f"SIM_WIND_SPD before {param_set('SIM_WIND_SPD', 0):g}", flush=True)
    m.mav.set_mode_send(m.target_system, mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED)
    while not m.motors_armed():
        m.mav.command_long_send(m.target_system, m.target_component, 400, 0, 1, 0, 0, 0, 0, 0, 0)
        m.recv_match(type="HEARTBEAT", blocking=True, timeout=2)
        time.sleep(0.5)
    m.mav.command_long_send(m.target_system, m.target_component, 22, 0, 0, 0, 0, 0, 0, 0, 10)
    while True:
        pos = m.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=5)
        if pos is not None and pos.relative_alt > 9500:
            break
    time.sleep(8)
    print(f"WIND at {boot_s():.2f}", flush=True)
    param_set("SIM_WIND_DIR", 270)
    param_set("SIM_WIND_SPD", 10)
    time.sleep(25)
    print(f"GPS off at {boot_s():.2f}", flush=True)
    param_set("SIM_GPS_DISABLE", 1)
    fix = None
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        msg = m.recv_match(type=["HEARTBEAT", "GPS_RAW_INT", "STATUSTEXT"], blocking=True, timeout=1)
        if msg is None:
            continue
        if msg.get_type() == "GPS_RAW_INT" and msg.fix_type != fix:
            fix = msg.fix_type
            print(f"GPS fix_type {fix} at {msg.time_usec / 1e6:.2f}", flush=True)
        elif msg.get_type() == "STATUSTEXT":
            print(f"TEXT {msg.text}", flush=True)
        elif msg.get_type() == "HEARTBEAT" and msg.get_srcSystem() == m.target_system and msg.custom_mode == LAND:
            print(f"MODE LAND at {boot_s():.2f}", flush=True)
            break
    while m.motors_armed() and time.monotonic() < deadline + 60:
        msg = m.recv_match(type=["HEARTBEAT", "STATUSTEXT"], blocking=True, timeout=1)
        if msg is not None and msg.get_type() == "STATUSTEXT":
            print(f"TEXT {msg.text}", flush=True)
    print(f"DISARMED {not m.motors_armed()}", flush=True)


if __name__ == "__main__":
    main()
