"""A synchronous pymavlink script in the style of the DroneKit era: connect, read telemetry, take off, land.

Written for one PX4 SITL vehicle (``udpin:0.0.0.0:14540``); under ``harness run`` every vehicle's copy
reaches its own vehicle, and ``time.sleep`` / ``recv_match(timeout=...)`` run on the simulation clock.
"""

import os
import sys
import time

from pymavlink import mavutil

master = mavutil.mavlink_connection("udpin:0.0.0.0:14540", source_system=255)
hb = master.wait_heartbeat(timeout=10)
if hb is None:
    sys.exit("no heartbeat")
print(f"heartbeat from system {master.target_system}", flush=True)
expected = os.environ.get("HARNESS_SYSID")
if expected is not None and master.target_system != int(expected):
    sys.exit(f"talking to system {master.target_system}, expected {expected}")

# ATTITUDE at 10 Hz, then count what arrives in 2 s
master.mav.command_long_send(
    master.target_system,
    master.target_component,
    mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
    0,
    30,
    100_000,
    0,
    0,
    0,
    0,
    0,
)
start = time.time()
boot_ms = []
while time.time() - start < 2.0:
    msg = master.recv_match(type="ATTITUDE", blocking=True, timeout=1.0)
    if msg is not None:
        boot_ms.append(msg.time_boot_ms)
print(f"ATTITUDE: {len(boot_ms)} in 2 s, time_boot_ms {boot_ms}", flush=True)
if not 18 <= len(boot_ms) <= 24:
    sys.exit(f"expected about 20 ATTITUDE in 2 s of sim time, got {len(boot_ms)}")

# wait until the vehicle has a home (GPS) and arm in Hold, take off with PX4's TAKEOFF mode
while True:
    home = master.recv_match(type="HOME_POSITION", blocking=True, timeout=1.0)
    if home is not None:
        break
    master.mav.command_long_send(
        master.target_system, master.target_component, mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 242, 0, 0, 0, 0, 0, 0
    )
master.arducopter_arm()
master.motors_armed_wait()
print("armed", flush=True)
master.set_mode("TAKEOFF")
while True:
    pos = master.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=1.0)
    if pos is not None and pos.relative_alt > 2000:
        break
print(f"in the air at t={time.monotonic():.2f}", flush=True)
time.sleep(3)
master.set_mode("LAND")
master.motors_disarmed_wait()
print(f"landed and disarmed at t={time.monotonic():.2f}", flush=True)
