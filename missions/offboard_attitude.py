#!/usr/bin/env python3
"""Offboard attitude: hold level, pitch 10 degrees nose down for 2 s (the vehicle accelerates north), level
again, then leave offboard (the vehicle brakes and holds) and land (gRPC API)."""

import asyncio

from mavsdk import System
from mavsdk.offboard import Attitude, OffboardError

THRUST = 0.53  # normalised thrust, a little over this airframe's hover thrust (MPC_THR_HOVER 0.52)


async def run() -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    async for health in drone.telemetry.health():
        if health.is_global_position_ok and health.is_home_position_ok:
            break
    await drone.action.arm()
    await drone.action.set_takeoff_altitude(10.0)
    await drone.action.takeoff()
    await asyncio.sleep(10)
    await drone.offboard.set_attitude(Attitude(0.0, 0.0, 0.0, THRUST))
    try:
        await drone.offboard.start()
    except OffboardError as error:
        print(f"Starting offboard mode failed: {error._result.result}")
        raise SystemExit(1) from None
    await asyncio.sleep(1)
    print("-- Pitch -10 degrees for 2 s")
    await drone.offboard.set_attitude(Attitude(0.0, -10.0, 0.0, THRUST))
    await asyncio.sleep(2)
    print("-- Level")
    await drone.offboard.set_attitude(Attitude(0.0, 0.0, 0.0, THRUST))
    await asyncio.sleep(1)
    await drone.offboard.stop()
    await asyncio.sleep(5)
    print("-- Landing")
    await drone.action.land()
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            print("-- Landed")
            break


if __name__ == "__main__":
    asyncio.run(run())
