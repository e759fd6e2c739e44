#!/usr/bin/env python3
"""How fresh is the telemetry a MAVSDK script sees? (gRPC API)

Takes off, then for 20 s (sim time) reads the attitude stream and compares each message's own timestamp
(the autopilot's sim time when it was sent) with the script's clock when it arrives. Prints a JSON line:
the number of messages and the median, 90th percentile and largest age in seconds.

    harness run --vehicles 1 --mission missions/telemetry_latency.py
"""

import asyncio
import json
import time

from mavsdk import System


async def run(seconds: float = 20.0) -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    async for health in drone.telemetry.health():
        if health.is_global_position_ok and health.is_home_position_ok:
            break
    await drone.action.arm()
    await drone.action.takeoff()
    ages = []
    end = time.monotonic() + seconds
    async for attitude in drone.telemetry.attitude_euler():
        now = time.monotonic()
        ages.append(now - attitude.timestamp_us / 1e6)
        if now >= end:
            break
    ages.sort()
    n = len(ages)
    print(json.dumps({"messages": n, "median_s": ages[n // 2], "p90_s": ages[int(n * 0.9)], "max_s": ages[-1]}))
    await drone.action.land()
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            break


if __name__ == "__main__":
    asyncio.run(run())
