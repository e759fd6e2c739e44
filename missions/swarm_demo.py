#!/usr/bin/env python3
"""The Quickstart demo: a swarm flocks over the radio to a waypoint and home again, then lands.

Every vehicle takes off to its own altitude and flies MAVSDK offboard velocity: towards the goal (60 m north, 40 m east of home), kept together and apart
by what its neighbours broadcast 5 times a (sim) second over `harness.net.radio` (separation, alignment,
cohesion). A vehicle turns for home only once it is at the goal and every neighbour it hears says it is
there too (or after 20 s of waiting; a leg gives up after 90 s) — the swarm turns as one. At home it lands.

    harness run --vehicles 3 --mission missions/swarm_demo.py --network builtin
"""

import asyncio
import json
import math

from mavsdk import System
from mavsdk.action import ActionError
from mavsdk.offboard import VelocityNedYaw

from harness.net import radio

R_EARTH = 6378137.0
GOAL_NE_M = (60.0, 40.0)
ARRIVED_M = 6.0
SEPARATION_M, SEPARATION_GAIN = 6.0, 0.8
COHESION_GAIN, ALIGNMENT_GAIN, GOAL_GAIN = 0.1, 0.3, 0.25
MAX_SPEED_M_S = 4.0
LEG_TIMEOUT_S = 90.0


def local(lat: float, lon: float, lat0: float, lon0: float) -> tuple[float, float]:
    return (math.radians(lat - lat0) * R_EARTH, math.radians(lon - lon0) * R_EARTH * math.cos(math.radians(lat0)))


async def flock_to(drone: System, home: object, goal: tuple[float, float], leg: str, wait_s: float) -> None:
    """Offboard velocity towards ``goal`` (north, east of home) with the flock, until the flock is there."""
    lat0, lon0 = home.latitude_deg, home.longitude_deg  # type: ignore[attr-defined]
    neighbours: dict[int, dict] = {}
    loop = asyncio.get_running_loop()
    arrived_at = None
    give_up = loop.time() + LEG_TIMEOUT_S  # a neighbour that cannot follow must not keep the others up forever
    while loop.time() < give_up:
        async for pv in drone.telemetry.position_velocity_ned():
            break
        async for pos in drone.telemetry.position():
            break
        now = loop.time()
        me_n, me_e = local(pos.latitude_deg, pos.longitude_deg, lat0, lon0)
        to_goal = (goal[0] - me_n, goal[1] - me_e)
        here = math.hypot(*to_goal) < ARRIVED_M
        if here and arrived_at is None:
            arrived_at = now
        vel = (pv.velocity.north_m_s, pv.velocity.east_m_s)
        radio.broadcast(
            json.dumps(
                {"lat": pos.latitude_deg, "lon": pos.longitude_deg, "vn": vel[0], "ve": vel[1], "leg": leg, "at": here}
            ).encode()
        )
        while (msg := await radio.receive_async(timeout=0)) is not None:
            neighbours[msg.src] = dict(json.loads(msg.payload), t=now)
        heard = [n for n in neighbours.values() if now - n["t"] < 2.0]
        everyone_there = all(n["at"] or n["leg"] != leg for n in heard)
        if arrived_at is not None and (everyone_there or now - arrived_at > wait_s):
            return
        vn, ve = GOAL_GAIN * to_goal[0], GOAL_GAIN * to_goal[1]
        if heard:
            rel = [local(n["lat"], n["lon"], pos.latitude_deg, pos.longitude_deg) for n in heard]
            vn += COHESION_GAIN * sum(r[0] for r in rel) / len(rel)
            ve += COHESION_GAIN * sum(r[1] for r in rel) / len(rel)
            vn += ALIGNMENT_GAIN * (sum(n["vn"] for n in heard) / len(heard) - vel[0])
            ve += ALIGNMENT_GAIN * (sum(n["ve"] for n in heard) / len(heard) - vel[1])
            for rn, re in rel:
                d = math.hypot(rn, re)
                if 0.01 < d < SEPARATION_M:
                    push = SEPARATION_GAIN * (SEPARATION_M - d) / d
                    vn -= push * rn
                    ve -= push * re
        speed = math.hypot(vn, ve)
        if speed > MAX_SPEED_M_S:
            vn, ve = vn * MAX_SPEED_M_S / speed, ve * MAX_SPEED_M_S / speed
        await drone.offboard.set_velocity_ned(VelocityNedYaw(vn, ve, 0.0, math.degrees(math.atan2(ve, vn))))
        await asyncio.sleep(0.2)


async def run() -> None:
    me = radio.vehicle()
    drone = System()
    await drone.connect(system_address="udpin://0.0.0.0:14540")
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    async for health in drone.telemetry.health():
        if health.is_global_position_ok and health.is_home_position_ok:
            break
    async for home in drone.telemetry.home():
        break
    await drone.action.set_takeoff_altitude(8.0 + 3.0 * me)
    for attempt in range(5):  # on a loaded machine MAVSDK may try to arm before it knows the autopilot is PX4
        try:
            await drone.action.arm()
            break
        except ActionError:
            if attempt == 4:
                raise
            await asyncio.sleep(1.0)
    await drone.action.takeoff()
    await asyncio.sleep(10)
    await drone.offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, 0.0))
    await drone.offboard.start()
    print(f"vehicle {me}: flocking to the waypoint", flush=True)
    await flock_to(drone, home, GOAL_NE_M, "out", wait_s=20.0)
    print(f"vehicle {me}: the flock is at the waypoint; home", flush=True)
    await flock_to(drone, home, (0.0, 0.0), "home", wait_s=20.0)
    await drone.offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, 0.0))
    await drone.offboard.stop()
    await drone.action.land()
    async for in_air in drone.telemetry.in_air():
        if not in_air:
            break
    print(f"vehicle {me}: landed", flush=True)


if __name__ == "__main__":
    asyncio.run(run())
