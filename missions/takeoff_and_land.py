#!/usr/bin/env python3
"""Take off, hover, land — written exactly like the MAVSDK-Python examples (old gRPC API).

Runs unmodified against a real PX4 SITL, and under ``harness run`` / ``harness demo`` on the sim clock,
where every vehicle of a swarm runs its own copy (the harness points port 14540 at each vehicle).
"""

import asyncio

from mavsdk import System


async def run() -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")

    print("Waiting for drone to connect...")
    async for state in drone.core.connection_state():
        if state.is_connected:
            print("-- Connected to drone!")
            break

    print("Waiting for drone to have a global position estimate...")
    async for health in drone.telemetry.health():
        if health.is_global_position_ok and health.is_home_position_ok:
            print("-- Global position estimate OK")
            break

    print("-- Arming")
    await drone.action.arm()

    print("-- Taking off")
    await drone.action.set_takeoff_altitude(10.0)
    await drone.action.takeoff()

    await asyncio.sleep(15)

    print("-- Landing")
    await drone.action.land()

    async for in_air in drone.telemetry.in_air():
        if not in_air:
            print("-- Landed")
            break


if __name__ == "__main__":
    asyncio.run(run())
