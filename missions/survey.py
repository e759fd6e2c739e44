#!/usr/bin/env python3
"""A lawnmower survey: upload a mission of 3 passes 60 m long, 15 m apart, at 20 m; fly it; RTL (gRPC API)."""

import asyncio
import math

from mavsdk import System
from mavsdk.mission import MissionItem, MissionPlan


def offset(lat: float, lon: float, north_m: float, east_m: float) -> tuple[float, float]:
    r = 6378137.0
    return lat + math.degrees(north_m / r), lon + math.degrees(east_m / (r * math.cos(math.radians(lat))))


def item(lat: float, lon: float, alt_m: float, speed_m_s: float) -> MissionItem:
    return MissionItem(
        lat,
        lon,
        alt_m,
        speed_m_s,
        True,
        float("nan"),
        float("nan"),
        MissionItem.CameraAction.NONE,
        float("nan"),
        float("nan"),
        1.0,
        float("nan"),
        float("nan"),
        MissionItem.VehicleAction.NONE,
    )


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
    items = []
    for i in range(3):
        east = 15.0 * i
        ends = (10.0, 70.0) if i % 2 == 0 else (70.0, 10.0)
        for north in ends:
            items.append(item(*offset(home.latitude_deg, home.longitude_deg, north, east), 20.0, 6.0))
    await drone.mission.set_return_to_launch_after_mission(True)
    print(f"-- Uploading {len(items)} waypoints")
    await drone.mission.upload_mission(MissionPlan(items))
    await drone.action.arm()
    await drone.mission.start_mission()
    async for progress in drone.mission.mission_progress():
        print(f"Mission progress: {progress.current}/{progress.total}")
        if progress.current == progress.total:
            break
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            print("-- Landed")
            break


if __name__ == "__main__":
    asyncio.run(run())
