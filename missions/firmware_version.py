#!/usr/bin/env python3
"""Read the autopilot's version and product information (gRPC API)."""

import asyncio

from mavsdk import System


async def run() -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    version = await drone.info.get_version()
    print(f"Flight software: {version.flight_sw_major}.{version.flight_sw_minor}.{version.flight_sw_patch}")
    print(f"Version: {version}")
    product = await drone.info.get_product()
    print(f"Product: {product}")


if __name__ == "__main__":
    asyncio.run(run())
