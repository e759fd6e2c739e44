#!/usr/bin/env python3
"""Reboot (MAVSDK action.reboot): on the ground, set a parameter, reboot the autopilot, wait until it is
healthy again and read the parameter back from the restarted flight stack (gRPC API)."""

import asyncio

from mavsdk import System


async def healthy(drone: System) -> None:
    async for health in drone.telemetry.health():
        if health.is_global_position_ok and health.is_home_position_ok:
            return


async def run() -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    await healthy(drone)
    await drone.param.set_param_float("MPC_XY_CRUISE", 6.5)
    texts: list[str] = []

    async def listen() -> None:
        async for text in drone.telemetry.status_text():
            texts.append(text.text)

    listener = asyncio.create_task(listen())
    await asyncio.sleep(0.5)
    print("-- Rebooting")
    await drone.action.reboot()
    await asyncio.sleep(2)
    print("-- Vehicle says:", [t for t in texts if "Reboot" in t])
    listener.cancel()
    await healthy(drone)
    print("-- Healthy again; MPC_XY_CRUISE =", await drone.param.get_param_float("MPC_XY_CRUISE"))
    await drone.action.arm()
    print("-- Armed after the reboot")
    await drone.action.disarm()


if __name__ == "__main__":
    asyncio.run(run())
