#!/usr/bin/env python3
"""The seed paper's use case: a DroneKit flocking script over the radio (separation, alignment, cohesion).

Written for one ArduCopter SITL vehicle (``tcp:127.0.0.1:5760``, DroneKit's examples' address); under
``harness run --firmware ardupilot`` every vehicle's copy reaches its own vehicle. Each vehicle takes off in
GUIDED, then 5 times a (sim) second broadcasts its position and velocity with ``harness.net.radio`` and
steers by what it heard in the last 2 s, by GUIDED velocity targets (SET_POSITION_TARGET_LOCAL_NED) as
DroneKit's ``send_ned_velocity`` example sends them. Every vehicle also wants to wander its own way at 1 m/s.

    harness run --firmware ardupilot --vehicles 5 --mission missions/flock_dronekit.py --network builtin -- 120
"""

import json
import math
import sys
import time

from dronekit import VehicleMode, connect
from pymavlink import mavutil

from harness.net import radio

R_EARTH = 6378137.0
SEPARATION_M, SEPARATION_GAIN = 6.0, 0.8
COHESION_GAIN, ALIGNMENT_GAIN = 0.15, 0.5
WANDER_M_S, MAX_SPEED_M_S = 1.0, 3.0
VELOCITY_ONLY = 0b0000111111000111


def local(lat, lon, lat0, lon0):
    return (math.radians(lat - lat0) * R_EARTH, math.radians(lon - lon0) * R_EARTH * math.cos(math.radians(lat0)))


def arm_and_takeoff(vehicle, altitude):
    while not vehicle.is_armable:
        time.sleep(1)
    vehicle.mode = VehicleMode("GUIDED")
    vehicle.armed = True
    while not vehicle.armed:
        time.sleep(1)
    vehicle.simple_takeoff(altitude)
    while vehicle.location.global_relative_frame.alt < altitude * 0.95:
        time.sleep(1)


def send_ned_velocity(vehicle, vn, ve, vd):
    msg = vehicle.message_factory.set_position_target_local_ned_encode(
        0, 0, 0, mavutil.mavlink.MAV_FRAME_LOCAL_NED, VELOCITY_ONLY, 0, 0, 0, vn, ve, vd, 0, 0, 0, 0, 0
    )
    vehicle.send_mavlink(msg)


def main(duration_s):
    me = radio.vehicle()
    wander = (WANDER_M_S * math.cos(2.4 * me), WANDER_M_S * math.sin(2.4 * me))
    vehicle = connect("tcp:127.0.0.1:5760", wait_ready=True)
    arm_and_takeoff(vehicle, 10.0)
    neighbours = {}
    end = time.time() + duration_s
    while time.time() < end:
        now = time.time()
        pos = vehicle.location.global_frame
        vn, ve, _ = vehicle.velocity
        radio.broadcast(json.dumps({"lat": pos.lat, "lon": pos.lon, "vn": vn, "ve": ve}).encode())
        while (msg := radio.receive(timeout=0)) is not None:
            neighbours[msg.src] = dict(json.loads(msg.payload), t=now)
        heard = [n for n in neighbours.values() if now - n["t"] < 2.0]
        cmd_n, cmd_e = wander
        if heard:
            rel = [local(n["lat"], n["lon"], pos.lat, pos.lon) for n in heard]
            cmd_n += COHESION_GAIN * sum(r[0] for r in rel) / len(rel)
            cmd_e += COHESION_GAIN * sum(r[1] for r in rel) / len(rel)
            cmd_n += ALIGNMENT_GAIN * (sum(n["vn"] for n in heard) / len(heard) - vn)
            cmd_e += ALIGNMENT_GAIN * (sum(n["ve"] for n in heard) / len(heard) - ve)
            for rn, re in rel:
                d = math.hypot(rn, re)
                if 0.01 < d < SEPARATION_M:
                    push = SEPARATION_GAIN * (SEPARATION_M - d) / d
                    cmd_n -= push * rn
                    cmd_e -= push * re
        speed = math.hypot(cmd_n, cmd_e)
        if speed > MAX_SPEED_M_S:
            cmd_n, cmd_e = cmd_n * MAX_SPEED_M_S / speed, cmd_e * MAX_SPEED_M_S / speed
        send_ned_velocity(vehicle, cmd_n, cmd_e, 0.0)
        time.sleep(0.2)
    send_ned_velocity(vehicle, 0.0, 0.0, 0.0)
    print(json.dumps({"vehicle": me, "neighbours_heard": sorted(neighbours)}), flush=True)
    vehicle.close()


if __name__ == "__main__":
    main(float(sys.argv[1]) if len(sys.argv) > 1 else 120.0)
