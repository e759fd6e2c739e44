#!/usr/bin/env python3
"""Take off, fly to a point 40 m north and 30 m east of home at 15 m, then return and land (gRPC API)."""

import asyncio
import math

from mavsdk import System

NORTH_M, EAST_M, ALT_M = 40.0, 30.0, 15.0


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
    lat = home.latitude_deg + math.degrees(NORTH_M / 6378137.0)
    lon = home.longitude_deg + math.degrees(EAST_M / (6378137.0 * math.cos(math.radians(home.latitude_deg))))
    await drone.action.arm()
    await drone.action.set_takeoff_altitude(ALT_M)
    await drone.action.takeoff()
    await asyncio.sleep(10)
    print(f"-- Going to {lat:.7f}, {lon:.7f}")
    await drone.action.goto_location(lat, lon, home.absolute_altitude_m + ALT_M, 0.0)
    async for pos in drone.telemetry.position():
        d_north = math.radians(pos.latitude_deg - lat) * 6378137.0
        d_east = math.radians(pos.longitude_deg - lon) * 6378137.0 * math.cos(math.radians(lat))
        if math.hypot(d_north, d_east) < 1.0:
            print("-- Arrived")
            break
    await asyncio.sleep(3)
    print("-- Returning to launch")
    await drone.action.return_to_launch()
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            print("-- Landed at home")
            break


if __name__ == "__main__":
    asyncio.run(run())
