#!/usr/bin/env python3
"""Manual control (as MAVSDK's manual_control example, with a fixed stick sequence instead of random ones):
take off, give stick input, switch to position control, fly forward, right, climb and hold with the sticks
resent every 0.1 s like a joystick, then altitude mode and land (gRPC API)."""

import asyncio

from mavsdk import System

# (x pitch forward, y roll right, z throttle 0..1 with 0.5 centre, r yaw, seconds)
STICKS = [
    (0.0, 0.0, 0.5, 0.0, 2.0),  # centred: hold
    (1.0, 0.0, 0.5, 0.0, 3.0),  # full forward
    (0.0, 0.0, 0.5, 0.0, 4.0),  # centred: brake and hold
    (0.0, 1.0, 0.5, 0.0, 3.0),  # full right
    (0.0, 0.0, 0.5, 0.0, 4.0),
    (0.0, 0.0, 1.0, 0.0, 2.0),  # full throttle: climb
    (0.0, 0.0, 0.5, 0.0, 3.0),
]


async def hold_sticks(drone: System, x: float, y: float, z: float, r: float, seconds: float) -> None:
    for _ in range(round(seconds * 10)):
        await drone.manual_control.set_manual_control_input(x, y, z, r)
        await asyncio.sleep(0.1)


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
    print("-- Arming")
    await drone.action.arm()
    await drone.action.set_takeoff_altitude(5.0)
    await drone.action.takeoff()
    await asyncio.sleep(8)
    await drone.manual_control.set_manual_control_input(0.0, 0.0, 0.5, 0.0)
    print("-- Starting position control")
    await drone.manual_control.start_position_control()
    for x, y, z, r, seconds in STICKS:
        print(f"-- Sticks x={x} y={y} z={z} r={r} for {seconds} s")
        await hold_sticks(drone, x, y, z, r, seconds)
    print("-- Starting altitude control")
    await drone.manual_control.start_altitude_control()
    await hold_sticks(drone, 0.5, 0.0, 0.5, 0.0, 2.0)
    await hold_sticks(drone, 0.0, 0.0, 0.5, 0.0, 1.0)
    print("-- Landing")
    await drone.action.land()
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            print("-- Landed")
            break


if __name__ == "__main__":
    asyncio.run(run())
