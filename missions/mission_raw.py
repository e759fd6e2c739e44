#!/usr/bin/env python3
"""A raw MAVLink mission (mission_raw plugin): takeoff, two waypoints, land; downloaded back and compared.

Items are MAVLink MISSION_ITEM_INT fields as a ground station would write them: frame 3 (global, altitude
relative to home), lat/lon in 1e-7 degrees.
"""

import asyncio
import math

from mavsdk import System
from mavsdk.mission_raw import MissionItem

FRAME_GLOBAL_RELATIVE_ALT = 3
NAV_WAYPOINT, NAV_LAND, NAV_TAKEOFF = 16, 21, 22


def offset(lat: float, lon: float, north_m: float, east_m: float) -> tuple[int, int]:
    r = 6378137.0
    lat2 = lat + math.degrees(north_m / r)
    lon2 = lon + math.degrees(east_m / (r * math.cos(math.radians(lat))))
    return round(lat2 * 1e7), round(lon2 * 1e7)


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
    plan = [(NAV_TAKEOFF, 0.0, 0.0, 10.0), (NAV_WAYPOINT, 25.0, 0.0, 10.0), (NAV_WAYPOINT, 25.0, -20.0, 12.0)]
    plan.append((NAV_LAND, 25.0, -20.0, 0.0))
    items = []
    for seq, (command, north, east, alt) in enumerate(plan):
        x, y = offset(home.latitude_deg, home.longitude_deg, north, east)
        items.append(
            MissionItem(seq, FRAME_GLOBAL_RELATIVE_ALT, command, 1 if seq == 0 else 0, 1, 0, 0, 0, float("nan"), x, y, alt, 0)
        )  # fmt: skip
    print(f"-- Uploading {len(items)} raw items")
    await drone.mission_raw.upload_mission(items)
    back = await drone.mission_raw.download_mission()
    same = [(i.command, i.x, i.y, round(i.z, 2)) for i in back] == [(i.command, i.x, i.y, i.z) for i in items]
    print(f"-- Downloaded {len(back)} items, identical: {same}")
    if not same:
        raise SystemExit("the vehicle holds a different mission than the one uploaded")
    await drone.action.arm()
    await drone.mission_raw.start_mission()
    async for progress in drone.mission_raw.mission_progress():
        print(f"Mission progress: {progress.current}/{progress.total}")
        if progress.current == progress.total:
            break
    async for armed in drone.telemetry.armed():
        if not armed:
            print("-- Landed and disarmed")
            break


if __name__ == "__main__":
    asyncio.run(run())
