#!/usr/bin/env python3
"""Take off to 10 m, hover for N seconds (argument, default 30), land: the benchmark's mission.

With a second argument BEACON_HZ > 0 the vehicle also broadcasts its position over the radio at that rate
and counts what it hears from the others (as swarm code does), so a run with ``--network builtin`` carries
real traffic.

harness run --vehicles 10 --mission missions/hover.py -- 60
harness run --vehicles 10 --network builtin --mission missions/hover.py -- 60 10
"""

import asyncio
import json
import sys

from mavsdk import System


async def beacon(drone: System, hz: float) -> None:
    from harness.net import radio

    heard = 0
    me = radio.vehicle()
    async for position in drone.telemetry.position_velocity_ned():
        radio.broadcast(json.dumps({"from": me, "north_m": position.position.north_m}).encode())
        while await radio.receive_async(timeout=0) is not None:
            heard += 1
        print(f"heard {heard}", flush=True)
        await asyncio.sleep(1.0 / hz)


async def run(hover_s: float, beacon_hz: float) -> None:
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    async for health in drone.telemetry.health():
        if health.is_global_position_ok and health.is_home_position_ok:
            break
    chatter = asyncio.ensure_future(beacon(drone, beacon_hz)) if beacon_hz > 0 else None
    await drone.action.set_takeoff_altitude(10.0)
    await drone.action.arm()
    await drone.action.takeoff()
    await asyncio.sleep(hover_s)
    await drone.action.land()
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            break
    if chatter is not None:
        chatter.cancel()


if __name__ == "__main__":
    args = [float(a) for a in sys.argv[1:]]
    asyncio.run(run(args[0] if args else 30.0, args[1] if len(args) > 1 else 0.0))
