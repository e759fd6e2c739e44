"""MAVSDK's gRPC API told to connect to an address that does not exist, inside ``asyncio.wait_for(..., 8)``, in
the style of MAVSDK-Python's show_debug_output.py: against a real PX4 it prints "Timed out" after 8 s."""

import asyncio
import time

from mavsdk import System


async def main() -> None:
    drone = System()
    start = time.monotonic()
    try:
        await asyncio.wait_for(drone.connect("invalid://bad:connection"), timeout=8)
    except TimeoutError:
        print(f"Timed out after {time.monotonic() - start:.3f} s")
    except Exception as e:
        print(f"Got exception: {e}")


asyncio.run(main())
