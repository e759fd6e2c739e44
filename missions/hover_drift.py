#!/usr/bin/env python3
"""Take off to 10 m, hold position for N seconds (argument, default 20), land; report how well it held.

The sweep example's mission (``scenarios/wind_sweep.toml``). While hovering it samples the vehicle's NED
position and reports, through ``harness.metrics`` (a JSON file in ``$HARNESS_RUN_DIR``, which ``harness
sweep`` turns into results.csv columns ``v<i>.<key>``):

- ``max_drift_m``: the largest horizontal distance from where the hover began;
- ``rms_alt_error_m``: root-mean-square distance from 10 m altitude;
- ``samples``: how many positions were taken.

harness run --vehicles 2 --mission missions/hover_drift.py -- 20
"""

import asyncio
import math
import sys

from mavsdk import System

from harness.metrics import report

ALTITUDE_M = 10.0


async def run(hover_s: float) -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    async for health in drone.telemetry.health():
        if health.is_global_position_ok and health.is_home_position_ok:
            break
    await drone.action.set_takeoff_altitude(ALTITUDE_M)
    await drone.action.arm()
    await drone.action.takeoff()
    async for pv in drone.telemetry.position_velocity_ned():
        if -pv.position.down_m > ALTITUDE_M - 0.3:
            n0, e0 = pv.position.north_m, pv.position.east_m
            break
    loop = asyncio.get_running_loop()
    end = loop.time() + hover_s  # sim time: the harness runs asyncio on the simulation clock
    drift, sq, samples = 0.0, 0.0, 0
    async for pv in drone.telemetry.position_velocity_ned():
        drift = max(drift, math.hypot(pv.position.north_m - n0, pv.position.east_m - e0))
        sq += (-pv.position.down_m - ALTITUDE_M) ** 2
        samples += 1
        if loop.time() >= end:
            break
    report(max_drift_m=drift, rms_alt_error_m=math.sqrt(sq / max(1, samples)), samples=samples)
    await drone.action.land()
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            break


if __name__ == "__main__":
    asyncio.run(run(float(sys.argv[1]) if len(sys.argv) > 1 else 20.0))
