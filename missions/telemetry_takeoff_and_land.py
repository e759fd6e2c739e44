#!/usr/bin/env python3
"""Telemetry during takeoff and landing: altitude and flight mode printed by two concurrent tasks (gRPC API)."""

import asyncio

from mavsdk import System


async def print_altitude(drone: System) -> None:
    previous = None
    async for position in drone.telemetry.position():
        altitude = round(position.relative_altitude_m, 1)
        if altitude != previous:
            print(f"Altitude: {altitude:.1f} m")
            previous = altitude


async def print_flight_mode(drone: System) -> None:
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
            print("-- Global position estimate OK")
            break
    watchers = [asyncio.ensure_future(print_altitude(drone)), asyncio.ensure_future(print_flight_mode(drone))]
    print("-- Arming")
    await drone.action.arm()
    print("-- Taking off")
    await drone.action.set_takeoff_altitude(5.0)
    await drone.action.takeoff()
    await asyncio.sleep(12)
    print("-- Landing")
    await drone.action.land()
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            break
    async for armed in drone.telemetry.armed():
        if not armed:
            print("-- Landed and disarmed")
            break
    for task in watchers:
        task.cancel()


if __name__ == "__main__":
    asyncio.run(run())
