#!/usr/bin/env python3
"""Geofence upload, then a goto that would leave it: the vehicle must turn back on its own (gRPC API).

An inclusion square of 40 m x 40 m centred on home. The goto target is 60 m north, outside the fence; at
the breach the vehicle's geofence action (GF_ACTION, return by default) takes over and it lands at home.
"""

import asyncio
import math

from mavsdk import System
from mavsdk.geofence import FenceType, GeofenceData, Point, Polygon


def offset(lat: float, lon: float, north_m: float, east_m: float) -> Point:
    r = 6378137.0
    return Point(lat + math.degrees(north_m / r), lon + math.degrees(east_m / (r * math.cos(math.radians(lat)))))


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
    lat, lon = home.latitude_deg, home.longitude_deg
    corners = [offset(lat, lon, n, e) for n, e in ((-20, -20), (20, -20), (20, 20), (-20, 20))]
    print("-- Uploading geofence")
    await drone.geofence.upload_geofence(GeofenceData([Polygon(corners, FenceType.INCLUSION)], []))
    await drone.action.arm()
    await drone.action.set_takeoff_altitude(10.0)
    await drone.action.takeoff()
    await asyncio.sleep(10)
    target = offset(lat, lon, 60.0, 0.0)
    print("-- Going 60 m north, outside the fence")
    await drone.action.goto_location(target.latitude_deg, target.longitude_deg, home.absolute_altitude_m + 10.0, 0.0)
    modes = []
    async for mode in drone.telemetry.flight_mode():
        if not modes or modes[-1] != mode:
            modes.append(mode)
            print(f"Flight mode: {mode}")
        if str(mode) == "RETURN_TO_LAUNCH":
            break
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            print("-- Landed")
            break


if __name__ == "__main__":
    asyncio.run(run())
