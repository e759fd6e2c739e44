#!/usr/bin/env python3
"""A swarm from one script: every vehicle takes off, forms a V behind vehicle 0, and the V flies north.

One process commands all vehicles with MAVSDK's gRPC API: one ``System()`` per vehicle, each with its own
``mavsdk_server`` (on its own free gRPC port). Under ``harness run --swarm-mission missions/formation.py``
the vehicles' addresses come from ``$HARNESS_VEHICLES`` (``docs/swarm.md``); without it (a real PX4 SITL
swarm, ``Tools/simulation/gazebo-classic/sitl_multiple_run.sh -n N``) vehicle i is ``udpin://0.0.0.0:14540+i``.

The formation is a leader-follower V: slot k > 0 is ``row = (k + 1) // 2`` places behind the apex and as many
to the left (odd k) or right (even k), ``SPACING_M`` apart. Every vehicle flies offboard velocity: the V's
own velocity plus a correction towards its slot (``GAIN`` per second, at most ``MAX_SPEED_M_S``), computed at
10 Hz of sim time from each vehicle's global position. Timeline (sim time after all are up): ``FORM_S`` to
form up, ``CRUISE_S`` at ``CRUISE_M_S`` north, then stop, and all land.

    harness run --vehicles 10 --swarm-mission missions/formation.py [-- CRUISE_S]
"""

import asyncio
import json
import math
import os
import sys

from mavsdk import System
from mavsdk.offboard import VelocityNedYaw

R_EARTH = 6378137.0
ALT_M = 10.0
SPACING_M = 8.0
CRUISE_M_S = 3.0
FORM_S, STOP_S = 20.0, 5.0
GAIN, MAX_SPEED_M_S = 0.8, 6.0


def addresses() -> list[str]:
    """Every vehicle's MAVSDK address: from the harness, or PX4 SITL's multi-vehicle ports."""
    listed = os.environ.get("HARNESS_VEHICLES")
    if listed:
        return [v["mavsdk_url"] for v in json.loads(listed)]
    count = int(os.environ.get("SWARM_SIZE", "3"))
    return [f"udpin://0.0.0.0:{14540 + i}" for i in range(count)]


def slot(k: int) -> tuple[float, float]:
    """North, east of slot k from the apex of the V, in metres."""
    row = (k + 1) // 2
    side = -1.0 if k % 2 else 1.0
    return (-row * SPACING_M, side * row * SPACING_M if row else 0.0)


def ned(lat: float, lon: float, lat0: float, lon0: float) -> tuple[float, float]:
    return (math.radians(lat - lat0) * R_EARTH, math.radians(lon - lon0) * R_EARTH * math.cos(math.radians(lat0)))


class Vehicle:
    def __init__(self, k: int, url: str) -> None:
        self.k = k
        self.url = url
        self.drone = System()
        self.position: tuple[float, float, float] | None = None  # lat, lon, relative altitude
        self._follower: asyncio.Task[None] | None = None

    async def connect(self) -> None:
        await self.drone.connect(system_address=self.url)
        async for state in self.drone.core.connection_state():
            if state.is_connected:
                break
        async for health in self.drone.telemetry.health():
            if health.is_global_position_ok and health.is_home_position_ok:
                break
        self._follower = asyncio.ensure_future(self._follow_position())

    async def _follow_position(self) -> None:
        async for pos in self.drone.telemetry.position():
            self.position = (pos.latitude_deg, pos.longitude_deg, pos.relative_altitude_m)

    async def take_off(self) -> None:
        await self.drone.action.set_takeoff_altitude(ALT_M)
        await self.drone.action.arm()
        await self.drone.action.takeoff()

    async def start_offboard(self) -> None:
        await self.drone.offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, 0.0))
        await self.drone.offboard.start()

    async def steer(self, target_ne: tuple[float, float], ref_vel_n: float, origin: tuple[float, float]) -> None:
        assert self.position is not None
        lat, lon, alt = self.position
        n, e = ned(lat, lon, *origin)
        vn = ref_vel_n + GAIN * (target_ne[0] - n)
        ve = GAIN * (target_ne[1] - e)
        speed = math.hypot(vn, ve)
        if speed > MAX_SPEED_M_S:
            vn, ve = vn * MAX_SPEED_M_S / speed, ve * MAX_SPEED_M_S / speed
        vd = max(-1.5, min(1.5, GAIN * (alt - ALT_M)))
        await self.drone.offboard.set_velocity_ned(VelocityNedYaw(vn, ve, vd, 0.0))

    async def land(self) -> None:
        await self.drone.offboard.stop()
        await self.drone.action.land()
        async for in_air in self.drone.telemetry.in_air():
            if not in_air:
                break


async def run(cruise_s: float) -> None:
    team = [Vehicle(k, url) for k, url in enumerate(addresses())]
    await asyncio.gather(*(v.connect() for v in team))
    print(f"-- {len(team)} vehicles connected")
    while any(v.position is None for v in team):
        await asyncio.sleep(0.1)
    # the V's apex starts 20 m north of the swarm's centre, which is the common origin of every position
    lat0 = sum(v.position[0] for v in team if v.position) / len(team)
    lon0 = sum(v.position[1] for v in team if v.position) / len(team)
    apex = (20.0, 0.0)
    await asyncio.gather(*(v.take_off() for v in team))
    print("-- taking off")
    await asyncio.sleep(12)
    await asyncio.gather(*(v.start_offboard() for v in team))
    print("-- forming up")
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    cruise_from, cruise_to = t0 + FORM_S, t0 + FORM_S + cruise_s
    announced = False
    while (now := loop.time()) < cruise_to + STOP_S:
        moving = cruise_from <= now < cruise_to
        if moving and not announced:
            print(f"-- cruising north at {CRUISE_M_S} m/s for {cruise_s:g} s")
            announced = True
        travelled = CRUISE_M_S * (min(max(now, cruise_from), cruise_to) - cruise_from)
        ref = (apex[0] + travelled, apex[1])
        await asyncio.gather(
            *(
                v.steer((ref[0] + slot(v.k)[0], ref[1] + slot(v.k)[1]), CRUISE_M_S if moving else 0.0, (lat0, lon0))
                for v in team
            )
        )
        await asyncio.sleep(0.1)
    print("-- landing")
    await asyncio.gather(*(v.land() for v in team))
    print("-- all landed")


if __name__ == "__main__":
    asyncio.run(run(float(sys.argv[1]) if len(sys.argv) > 1 else 40.0))
