#!/usr/bin/env python3
"""Take off to 10 m, hover for N seconds (argument, default 30), land: the benchmark's mission for ArduCopter
vehicles, with DroneKit (``missions/hover.py`` is the MAVSDK one for PX4 vehicles).

With a second argument BEACON_HZ > 0 the vehicle also broadcasts its position over the radio at that rate
and counts what it hears from the others.

harness run --firmware ardupilot --vehicles 10 --network builtin --mission missions/hover_dronekit.py -- 60 10
"""

import json
import sys
import threading
import time

from dronekit import VehicleMode, connect


def beacon(vehicle, hz, stop):
    from harness.net import radio

    heard = 0
    me = radio.vehicle()
    while not stop.is_set():
        radio.broadcast(json.dumps({"from": me, "north_m": vehicle.location.local_frame.north}).encode())
        while radio.receive(timeout=0) is not None:
            heard += 1
        time.sleep(1.0 / hz)
    print(f"heard {heard}", flush=True)


def main(hover_s, beacon_hz):
    vehicle = connect("tcp:127.0.0.1:5760", wait_ready=True)
    while not vehicle.is_armable:
        time.sleep(0.5)
    stop = threading.Event()
    chatter = None
    if beacon_hz > 0:
        chatter = threading.Thread(target=beacon, args=(vehicle, beacon_hz, stop), daemon=True)
        chatter.start()
    vehicle.mode = VehicleMode("GUIDED")
    vehicle.armed = True
    while not vehicle.armed:
        time.sleep(0.2)
    vehicle.simple_takeoff(10.0)
    while vehicle.location.global_relative_frame.alt < 9.5:
        time.sleep(0.5)
    time.sleep(hover_s)
    vehicle.mode = VehicleMode("LAND")
    while vehicle.armed:
        time.sleep(0.5)
    stop.set()
    if chatter is not None:
        chatter.join()
    vehicle.close()


if __name__ == "__main__":
    args = [float(a) for a in sys.argv[1:]]
    main(args[0] if args else 30.0, args[1] if len(args) > 1 else 0.0)
