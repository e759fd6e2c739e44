#!/usr/bin/env python3
"""A square waypoint mission on the native MAVSDK >= 4 asyncio API, driven by its telemetry streams.

Uploads four corners 15 m apart at 8 m altitude, arms, starts the mission, follows ``mission_progress`` and
``position`` streams until the last item, then returns to launch and waits for ``in_air`` to turn false.
Argument: the side in metres (default 15).
"""

import asyncio
import math
import sys

from mavsdk import ComponentType
from mavsdk.asyncio import Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mission import MissionAsync, MissionItem, MissionPlan
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

EARTH_M = 6_378_137.0


def offset(lat: float, lon: float, north_m: float, east_m: float) -> tuple[float, float]:
    dlat = math.degrees(north_m / EARTH_M)
    dlon = math.degrees(east_m / (EARTH_M * math.cos(math.radians(lat))))
    return lat + dlat, lon + dlon


def corner(lat: float, lon: float, north_m: float, east_m: float) -> MissionItem:
    la, lo = offset(lat, lon, north_m, east_m)
    return MissionItem(
        latitude_deg=la,
        longitude_deg=lo,
        relative_altitude_m=8.0,
        speed_m_s=6.0,
        is_fly_through=True,
        acceptance_radius_m=1.0,
    )


async def run(side_m: float) -> None:
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    await mavsdk.add_any_connection("udpin://0.0.0.0:14540")
    system = await mavsdk.first_autopilot(timeout_s=10.0)
    if system is None:
        raise SystemExit("no autopilot found")
    telemetry, action, mission = TelemetryAsync(system), ActionAsync(system), MissionAsync(system)

    async for health in telemetry.subscribe_health():
        if health.is_global_position_ok and health.is_home_position_ok and health.is_armable:
            break
    async for home in telemetry.subscribe_home():
        break
    print(f"-- Home at {home.latitude_deg:.6f}, {home.longitude_deg:.6f}")

    lat, lon = home.latitude_deg, home.longitude_deg
    plan = MissionPlan(
        [corner(lat, lon, n, e) for n, e in ((side_m, 0.0), (side_m, side_m), (0.0, side_m), (0.0, 0.0))]
    )
    await mission.set_return_to_launch_after_mission(False)
    await mission.upload_mission(plan)
    print("-- Uploaded 4 corners")
    await action.arm()
    await mission.start_mission()
    print("-- Mission started")

    async def report_positions() -> None:
        loop, last = asyncio.get_running_loop(), -math.inf
        async for pos in telemetry.subscribe_position():
            if loop.time() - last >= 2.0:
                last = loop.time()
                n = math.radians(pos.latitude_deg - lat) * EARTH_M
                print(f"   position {n:6.1f} m north, {pos.relative_altitude_m:5.1f} m up")

    reporter = asyncio.ensure_future(report_positions())
    async for progress in mission.subscribe_mission_progress():
        print(f"-- Progress {progress.current}/{progress.total}")
        if progress.total and progress.current == progress.total:
            break
    reporter.cancel()
    print("-- Returning to launch")
    await action.return_to_launch()
    async for in_air in telemetry.subscribe_in_air():
        if not in_air:
            break
    print("-- Landed")
    mavsdk.destroy()


if __name__ == "__main__":
    asyncio.run(run(float(sys.argv[1]) if len(sys.argv) > 1 else 15.0))
