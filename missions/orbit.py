#!/usr/bin/env python3
"""Orbit: circle a point 20 m north of home at radius 10 m and 3 m/s, facing the centre, for 45 s; then
return to launch (gRPC API)."""

import asyncio
import math

from mavsdk import System
from mavsdk.action import OrbitYawBehavior


async def run() -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    async for health in drone.telemetry.health():
        if health.is_global_position_ok and health.is_home_position_ok:
            break
    async for home in drone.telemetry.home():
        break
    await drone.action.arm()
    await drone.action.set_takeoff_altitude(10.0)
    await drone.action.takeoff()
    await asyncio.sleep(10)
    centre_lat = home.latitude_deg + math.degrees(20.0 / 6378137.0)
    print("-- Orbiting")
    await drone.action.do_orbit(
        radius_m=10.0,
        velocity_ms=3.0,
        yaw_behavior=OrbitYawBehavior.HOLD_FRONT_TO_CIRCLE_CENTER,
        latitude_deg=centre_lat,
        longitude_deg=home.longitude_deg,
        absolute_altitude_m=home.absolute_altitude_m + 10.0,
    )
    await asyncio.sleep(45)
    print("-- Returning to launch")
    await drone.action.return_to_launch()
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            print("-- Landed")
            break


if __name__ == "__main__":
    asyncio.run(run())
