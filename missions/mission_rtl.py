#!/usr/bin/env python3
"""Mission upload, start and progress, then an explicit return to launch (gRPC API).

Three waypoints at 15 m: 30 m north, then 30 m north and 30 m east, then 30 m east. When the last one is
reached the script commands RTL itself (the mission does not return on its own) and waits for the landing.
"""

import asyncio
import math

from mavsdk import System
from mavsdk.mission import MissionItem, MissionPlan


def offset(lat: float, lon: float, north_m: float, east_m: float) -> tuple[float, float]:
    r = 6378137.0
    return lat + math.degrees(north_m / r), lon + math.degrees(east_m / (r * math.cos(math.radians(lat))))


def waypoint(lat: float, lon: float) -> MissionItem:
    nan = float("nan")
    return MissionItem(
        lat, lon, 15.0, 5.0, True, nan, nan, MissionItem.CameraAction.NONE, nan, nan, 1.0, nan, nan,
        MissionItem.VehicleAction.NONE,
    )  # fmt: skip


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
    legs = [(30.0, 0.0), (30.0, 30.0), (0.0, 30.0)]
    plan = MissionPlan([waypoint(*offset(home.latitude_deg, home.longitude_deg, n, e)) for n, e in legs])
    await drone.mission.set_return_to_launch_after_mission(False)
    print("-- Uploading mission")
    await drone.mission.upload_mission(plan)
    print("-- Arming")
    await drone.action.arm()
    print("-- Starting mission")
    await drone.mission.start_mission()
    async for progress in drone.mission.mission_progress():
        print(f"Mission progress: {progress.current}/{progress.total}")
        if progress.current == progress.total:
            break
    print("-- Returning to launch")
    await drone.action.return_to_launch()
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            print("-- Landed")
            break


if __name__ == "__main__":
    asyncio.run(run())
