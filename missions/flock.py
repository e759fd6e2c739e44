#!/usr/bin/env python3
"""Flocking over the radio: separation, alignment and cohesion (Reynolds), flown with MAVSDK offboard velocity.

Each vehicle knows only what its neighbours told it: 5 times a (sim) second it broadcasts its position and
velocity with `harness.net.radio` and steers by what it heard in the last 2 s. Every vehicle also wants to
wander in its own direction at 1 m/s; the flock holds together only as long as the radio does.

    harness run --vehicles 5 --mission missions/flock.py --network builtin -- 120
"""

import asyncio
import json
import math
import sys

from mavsdk import System
from mavsdk.offboard import VelocityNedYaw

from harness.net import radio

R_EARTH = 6378137.0
SEPARATION_M, SEPARATION_GAIN = 6.0, 0.8
COHESION_GAIN, ALIGNMENT_GAIN = 0.15, 0.5
WANDER_M_S, MAX_SPEED_M_S = 1.0, 3.0


def local(lat: float, lon: float, lat0: float, lon0: float) -> tuple[float, float]:
    return (math.radians(lat - lat0) * R_EARTH, math.radians(lon - lon0) * R_EARTH * math.cos(math.radians(lat0)))


async def run(duration_s: float) -> None:
    me = radio.vehicle()
    wander = (WANDER_M_S * math.cos(2.4 * me), WANDER_M_S * math.sin(2.4 * me))
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    async for health in drone.telemetry.health():
        if health.is_global_position_ok and health.is_home_position_ok:
            break
    await drone.action.set_takeoff_altitude(10.0)
    await drone.action.arm()
    await drone.action.takeoff()
    await asyncio.sleep(12)
    await drone.offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, 0.0))
    await drone.offboard.start()

    neighbours: dict[int, dict[str, float]] = {}
    loop = asyncio.get_running_loop()
    end = loop.time() + duration_s
    while loop.time() < end:
        async for pv in drone.telemetry.position_velocity_ned():
            break
        async for pos in drone.telemetry.position():
            break
        now = loop.time()
        vel = (pv.velocity.north_m_s, pv.velocity.east_m_s)
        radio.broadcast(
            json.dumps({"lat": pos.latitude_deg, "lon": pos.longitude_deg, "vn": vel[0], "ve": vel[1]}).encode()
        )
        while (msg := await radio.receive_async(timeout=0)) is not None:
            neighbours[msg.src] = dict(json.loads(msg.payload), t=now)
        heard = [n for n in neighbours.values() if now - n["t"] < 2.0]
        vn, ve = wander
        if heard:
            rel = [local(n["lat"], n["lon"], pos.latitude_deg, pos.longitude_deg) for n in heard]
            cn = sum(r[0] for r in rel) / len(rel)
            ce = sum(r[1] for r in rel) / len(rel)
            vn += COHESION_GAIN * cn + ALIGNMENT_GAIN * (sum(n["vn"] for n in heard) / len(heard) - vel[0])
            ve += COHESION_GAIN * ce + ALIGNMENT_GAIN * (sum(n["ve"] for n in heard) / len(heard) - vel[1])
            for rn, re in rel:
                d = math.hypot(rn, re)
                if 0.01 < d < SEPARATION_M:
                    push = SEPARATION_GAIN * (SEPARATION_M - d) / d
                    vn -= push * rn
                    ve -= push * re
        speed = math.hypot(vn, ve)
        if speed > MAX_SPEED_M_S:
            vn, ve = vn * MAX_SPEED_M_S / speed, ve * MAX_SPEED_M_S / speed
        await drone.offboard.set_velocity_ned(VelocityNedYaw(vn, ve, 0.0, 0.0))
        await asyncio.sleep(0.2)
    await drone.offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, 0.0))
    print(json.dumps({"vehicle": me, "neighbours_heard": sorted(neighbours)}))


if __name__ == "__main__":
    asyncio.run(run(float(sys.argv[1]) if len(sys.argv) > 1 else 120.0))
