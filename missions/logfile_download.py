#!/usr/bin/env python3
"""Log download (as MAVSDK's logfile_download example): take off to 5 m, land, then list the vehicle's
flight logs and download each as ULog into the run directory (gRPC API)."""

import asyncio
import os
import sys

from mavsdk import System


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
    await drone.action.set_takeoff_altitude(5.0)
    await drone.action.arm()
    await drone.action.takeoff()
    await asyncio.sleep(10)
    await drone.action.land()
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            print("-- Landed")
            break
    entries = await drone.log_files.get_entries()
    for entry in entries:
        print(f"Log {entry.id} from {entry.date}, {entry.size_bytes} bytes")
    out_dir = os.environ.get("HARNESS_RUN_DIR", ".")
    for entry in entries:
        filename = os.path.join(out_dir, f"log-{entry.id}.ulg")
        previous = -1
        async for progress in drone.log_files.download_log_file(entry, filename):
            percent = round(progress.progress * 100)
            if percent != previous:
                sys.stdout.write(f"\r{percent} %")
                previous = percent
        print(f"\n-- Downloaded {filename}")


if __name__ == "__main__":
    asyncio.run(run())
