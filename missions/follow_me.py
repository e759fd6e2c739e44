#!/usr/bin/env python3
"""Follow me (as MAVSDK's follow_me_example): take off, start follow-me, and be a target that walks 40 m
north at 2 m/s, then 20 m east, reported at 5 Hz; the vehicle follows 6 m behind it at 8 m above home,
nose on the target; stop, land (gRPC API)."""

import asyncio
import math

from mavsdk import System
from mavsdk.follow_me import Config, TargetLocation

EARTH_RADIUS_M = 6378137.0


async def run() -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            print("-- Connected to drone!")
            break
    async for health in drone.telemetry.health():
        if health.is_global_position_ok and health.is_home_position_ok:
            break
    async for home in drone.telemetry.home():
        break
    print("-- Arming")
    await drone.action.arm()
    conf = Config(8.0, 6.0, 0.1, Config.FollowAltitudeMode.CONSTANT, 8.0, 180.0)
    await drone.follow_me.set_config(conf)
    print("-- Taking Off")
    await drone.action.takeoff()
    await asyncio.sleep(8)
    print("-- Starting Follow Me Mode")
    await drone.follow_me.start()
    north, east = 8.0, 0.0
    legs = [(2.0, 0.0, 20.0), (0.0, 2.0, 10.0)]  # (v_north, v_east, seconds)
    for v_north, v_east, seconds in legs:
        for _ in range(int(seconds * 5)):
            north += v_north * 0.2
            east += v_east * 0.2
            lat = home.latitude_deg + math.degrees(north / EARTH_RADIUS_M)
            lon = home.longitude_deg + math.degrees(east / (EARTH_RADIUS_M * math.cos(math.radians(home.latitude_deg))))
            target = TargetLocation(lat, lon, home.absolute_altitude_m, v_north, v_east, 0.0)
            await drone.follow_me.set_target_location(target)
            await asyncio.sleep(0.2)
        print(f"-- Target at {north:.0f} m north, {east:.0f} m east")
    print("-- Stopping Follow Me Mode")
    await drone.follow_me.stop()
    await asyncio.sleep(3)
    print("-- Landing")
    await drone.action.land()
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            print("-- Landed")
            break


if __name__ == "__main__":
    asyncio.run(run())
