#!/usr/bin/env python3
"""Take off, hover (argument: seconds, default 15), land with the native MAVSDK ≥ 4 API (synchronous calls)."""

import sys
import time

from mavsdk import ComponentType, Configuration, Mavsdk
from mavsdk.plugins.action import Action
from mavsdk.plugins.telemetry import Telemetry


def main() -> None:
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    mavsdk.add_any_connection("udpin://0.0.0.0:14540")
    system = mavsdk.first_autopilot(10.0)
    if system is None:
        raise SystemExit("no autopilot found")
    telemetry, action = Telemetry(system), Action(system)
    while True:
        health = telemetry.health()
        if health.is_global_position_ok and health.is_home_position_ok and health.is_armable:
            break
        time.sleep(0.5)
    print("-- Arming")
    action.arm()
    print("-- Taking off")
    action.takeoff()
    time.sleep(float(sys.argv[1]) if len(sys.argv) > 1 else 15.0)
    print(f"-- Hovering at {telemetry.position().relative_altitude_m:.1f} m, landing")
    action.land()
    while telemetry.in_air():
        time.sleep(0.5)
    print("-- Landed")
    mavsdk.destroy()


if __name__ == "__main__":
    main()
