#!/usr/bin/env python3
"""Print position, flight mode and battery once per (simulated) second for N seconds (default 10)."""

import asyncio
import sys

from mavsdk import System


async def run(seconds: int) -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    for _ in range(seconds):
        async for pos in drone.telemetry.position():
            break
        async for mode in drone.telemetry.flight_mode():
            break
        async for battery in drone.telemetry.battery():
            break
        print(
            f"lat {pos.latitude_deg:.6f} lon {pos.longitude_deg:.6f} rel_alt {pos.relative_altitude_m:.1f} m "
            f"mode {mode} battery {battery.remaining_percent:.0f} %"
        )
        await asyncio.sleep(1)


if __name__ == "__main__":
    asyncio.run(run(int(sys.argv[1]) if len(sys.argv) > 1 else 10))
