#!/usr/bin/env python3
"""Take off to 10 m, hover for N seconds (argument, default 30), land: the benchmark's mission.

harness run --vehicles 10 --mission missions/hover.py -- 60
"""

import asyncio
import sys

from mavsdk import System


async def run(hover_s: float) -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    async for health in drone.telemetry.health():
        if health.is_global_position_ok and health.is_home_position_ok:
            break
    await drone.action.set_takeoff_altitude(10.0)
    await drone.action.arm()
    await drone.action.takeoff()
    await asyncio.sleep(hover_s)
    await drone.action.land()
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            break


if __name__ == "__main__":
    asyncio.run(run(float(sys.argv[1]) if len(sys.argv) > 1 else 30.0))
