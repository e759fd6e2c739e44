"""A pymavlink ground station that points each vehicle's gimbal at set sim times (``harness run`` runs a copy per
vehicle; ``time`` is the sim clock): MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW to (-45, 30) deg at 3 s of sim time,
to (-90, -60) deg at 5 s, then it ends at 7 s. It prints each command's send time and result, which
``test_gimbal.py`` compares with world.mcap. The vehicle listed in ``GIMBAL_NONE`` (an ArduCopter one, over its
SERIAL0 TCP port) is only asked once, and must refuse: it has no gimbal.
"""

import os
import sys
import time

from pymavlink import mavutil

vehicle = int(os.environ["HARNESS_VEHICLE"])
no_gimbal = vehicle == int(os.environ.get("GIMBAL_NONE", "-1"))
url = "tcp:127.0.0.1:5760" if no_gimbal else "udpin:0.0.0.0:14540"
master = mavutil.mavlink_connection(url, source_system=255)
if master.wait_heartbeat(timeout=10) is None:
    sys.exit("no heartbeat")


def pitchyaw(pitch_deg: float, yaw_deg: float, at_s: float) -> int:
    time.sleep(max(0.0, at_s - time.monotonic()))
    sent = time.monotonic()
    master.mav.command_long_send(
        master.target_system, master.target_component, 1000, 0, pitch_deg, yaw_deg, float("nan"), float("nan"), 0, 0, 0
    )
    while True:
        ack = master.recv_match(type="COMMAND_ACK", blocking=True, timeout=5.0)
        if ack is None:
            sys.exit("no COMMAND_ACK")
        if ack.command == 1000:
            break
    print(f"pitchyaw {pitch_deg:g} {yaw_deg:g} sent at {sent:.6f} result {ack.result}", flush=True)
    return ack.result


if no_gimbal:
    result = pitchyaw(-45.0, 30.0, 3.0)
    sys.exit(0 if result != mavutil.mavlink.MAV_RESULT_ACCEPTED else "a vehicle without a gimbal accepted")
for pitch, yaw, at in ((-45.0, 30.0, 3.0), (-90.0, -60.0, 5.0)):
    if pitchyaw(pitch, yaw, at) != mavutil.mavlink.MAV_RESULT_ACCEPTED:
        sys.exit("refused")
time.sleep(max(0.0, 7.0 - time.monotonic()))
