"""A DroneKit script written for one PX4 SITL vehicle: connect, read attitude, arm, take off, land.

DroneKit (``pip install dronekit2``, imports as ``dronekit``) runs its reader thread on pymavlink's
``select`` loop; under ``harness run`` every copy of this script reaches its own vehicle and waits on the
simulation clock.
"""

import os
import sys
import time

from dronekit import VehicleMode, connect

vehicle = connect("udpin:0.0.0.0:14540", wait_ready=["attitude", "gps_0", "mode", "armed"], heartbeat_timeout=30)
sysid = os.environ.get("HARNESS_SYSID")
print(f"connected: mode {vehicle.mode.name}, system {vehicle._master.target_system}", flush=True)
if sysid is not None and vehicle._master.target_system != int(sysid):
    sys.exit(f"talking to system {vehicle._master.target_system}, expected {sysid}")

attitudes = []
vehicle.add_attribute_listener("attitude", lambda _v, _name, att: attitudes.append(time.monotonic()))
time.sleep(2.0)
print(f"attitude updates in 2 s: {len(attitudes)}", flush=True)
if len(attitudes) < 15:
    sys.exit(f"expected about 20 attitude updates (10 Hz) in 2 s of sim time, got {len(attitudes)}")

while vehicle.home_location is None:  # dronekit2 takes home from PX4's HOME_POSITION (at the first GPS fix)
    time.sleep(0.5)
time.sleep(10.0)  # PX4's EKF2 trusts the GPS once its checks have passed for 10 s (DroneKit cannot see it)
vehicle.armed = True
while not vehicle.armed:
    time.sleep(0.2)
print("armed", flush=True)
vehicle.mode = VehicleMode("TAKEOFF")
while vehicle.location.global_relative_frame.alt < 2.0:
    time.sleep(0.2)
print(f"in the air at t={time.monotonic():.2f}", flush=True)
time.sleep(3)
vehicle.mode = VehicleMode("LAND")
while vehicle.armed:
    time.sleep(0.5)
print(f"landed and disarmed at t={time.monotonic():.2f}", flush=True)
vehicle.close()
