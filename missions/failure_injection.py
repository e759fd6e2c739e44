#!/usr/bin/env python3
"""Failure injection (as MAVSDK's failure_injection example): take off, climb to 20 m, switch the GPS off;
PX4 dead-reckons, then declares the position lost and descends (AUTO.LAND without a position); print the
flight modes until it has landed, then switch the GPS back on (gRPC API)."""

import asyncio

from mavsdk import System
from mavsdk.failure import FailureType, FailureUnit


async def print_modes(drone: System) -> None:
    previous = None
    async for mode in drone.telemetry.flight_mode():
        if mode != previous:
            print(f"Flight mode: {mode}")
            previous = mode


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
    print("-- Enabling failure injection")
    await drone.param.set_param_int("SYS_FAILURE_EN", 1)
    modes = asyncio.ensure_future(print_modes(drone))
    await drone.action.arm()
    await drone.action.takeoff()
    await asyncio.sleep(5)
    async for position in drone.telemetry.position():
        break
    print("-- Flying up")
    await drone.action.goto_location(
        position.latitude_deg, position.longitude_deg, position.absolute_altitude_m + 20.0, 0
    )
    await asyncio.sleep(10)
    print("-- Injecting GPS failure")
    await drone.failure.inject(FailureUnit.SENSOR_GPS, FailureType.OFF, instance=0)
    async for health in drone.telemetry.health():
        if not health.is_global_position_ok:
            print("-- Global position lost")
            break
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            print("-- Landed without GPS")
            break
    print("-- GPS back on")
    await drone.failure.inject(FailureUnit.SENSOR_GPS, FailureType.OK, instance=0)
    await drone.param.set_param_int("SYS_FAILURE_EN", 0)
    modes.cancel()


if __name__ == "__main__":
    asyncio.run(run())
