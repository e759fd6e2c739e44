"""One mission script for the whole swarm (``harness run --swarm-mission PATH``, ``[swarm] mission``).

A per-vehicle mission is told its one vehicle (``HARNESS_VEHICLE``, ``HARNESS_MAVLINK_PORT``) and its
standard addresses (``udpin://0.0.0.0:14540``) are pointed there. A swarm mission commands every vehicle
from one process, so it is told all of them instead, in one environment variable:

``HARNESS_VEHICLES``
    a JSON list, one object per vehicle in index order::

        {"vehicle": 0, "sysid": 1, "firmware": "px4",
         "mavsdk_url": "udpout://127.0.0.1:14580", "pymavlink_url": "udpout:127.0.0.1:14580",
         "udp_port": 14580, "tcp_port": null}

    ``mavsdk_url`` is what ``System.connect(system_address=…)`` (gRPC API) or ``add_any_connection``
    (native API) takes, ``pymavlink_url`` what ``mavutil.mavlink_connection`` takes; ``tcp_port`` is the
    SERIAL0 port of an ArduPilot vehicle (null for PX4).

The swarm mission is a type-0 subscriber like any mission (sim clock, phase 0, exit code), with no vehicle
of its own (``vehicle = -1`` on the channel). The standard addresses are not redirected; the vehicles' own are
its *team*: MAVLink to them is settled like a one-vehicle mission's, and a MAVSDK ``udpout://`` URL to one
listens on a port announced to that vehicle (``harness.core.endpoints.team_mavsdk_url``). Its
exit code is every vehicle's ``mission_exit_code`` in ``summary.json`` unless the vehicle also has a
mission of its own.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from harness.autopilot.firmware import Firmware
from harness.core.endpoints import ENV_VEHICLES, sysid

SWARM_VEHICLE = -1
"""The channel's vehicle index of a swarm mission (it belongs to no one vehicle)."""
SWARM_PEER_PREFIX = "swarm:"
"""Channel name of the swarm mission: ``swarm:<script file name>``."""


@dataclass(frozen=True, slots=True)
class SwarmVehicle:
    """One vehicle as a swarm mission sees it (an element of ``HARNESS_VEHICLES``)."""

    vehicle: int
    sysid: int
    firmware: str
    mavsdk_url: str
    pymavlink_url: str
    udp_port: int
    tcp_port: int | None


def swarm_vehicles(
    n: int,
    api_port_base: int,
    firmware_of: Callable[[int], Firmware],
    tcp_port_of: Callable[[int], int],
    host: str = "127.0.0.1",
) -> list[SwarmVehicle]:
    """Every vehicle of a run: vehicle ``i`` listens on UDP ``api_port_base + i`` (and, as an ArduPilot
    vehicle, on TCP ``tcp_port_of(i)``)."""
    out = []
    for i in range(n):
        port = api_port_base + i
        fw = firmware_of(i)
        out.append(
            SwarmVehicle(
                vehicle=i,
                sysid=sysid(i),
                firmware=fw.value,
                mavsdk_url=f"udpout://{host}:{port}",
                pymavlink_url=f"udpout:{host}:{port}",
                udp_port=port,
                tcp_port=tcp_port_of(i) if fw is Firmware.ARDUPILOT else None,
            )
        )
    return out


def vehicles_json(vehicles: Sequence[SwarmVehicle]) -> str:
    """The value of ``HARNESS_VEHICLES``."""
    return json.dumps([asdict(v) for v in vehicles], separators=(",", ":"))


def parse_vehicles(text: str) -> list[SwarmVehicle]:
    """``HARNESS_VEHICLES`` back into its vehicles (the inverse of :func:`vehicles_json`)."""
    items: Any = json.loads(text)
    if not isinstance(items, list):
        raise ValueError(f"{ENV_VEHICLES} must be a JSON list, got {type(items).__name__}")
    return [SwarmVehicle(**item) for item in items]


ONE_VEHICLE_ENV = ("HARNESS_VEHICLE", "HARNESS_SYSID", "HARNESS_MAVLINK_PORT", "HARNESS_MAVLINK_TCP_PORT")
"""What tells a mission its one vehicle (and redirects its standard addresses): never given to a swarm mission."""


def swarm_env(env: Mapping[str, str], vehicles: Sequence[SwarmVehicle]) -> dict[str, str]:
    """The swarm mission's environment: ``env`` without any one vehicle's variables, with ``HARNESS_VEHICLES``."""
    out = {k: v for k, v in env.items() if k not in ONE_VEHICLE_ENV}
    out[ENV_VEHICLES] = vehicles_json(vehicles)
    return out


MISSION_PRELOAD = (
    "harness.cli",
    "harness.simclock.mission",
    "harness.simclock.udp",
    "mavsdk?",
    "mavsdk.plugins.action?",
    "mavsdk.plugins.telemetry?",
)
"""What a mission process imports before it runs its script: the fork server imports it once for all
(``Children(fork_preload=...)``, ``harness/run/forkserver.py``); a name ending in ``?`` only where it is installed.
MAVSDK's package loads ``libcmavsdk.so`` and starts no thread: each mission puts the loaded library on its own sim
clock after the fork (``mavsdk_compat.on_sim_clock``), and saves ≈ 50 ms of CPU importing it."""


def mission_argv(
    python: str, address: str, vehicle: int, script: Path, args: Sequence[str], name: str | None = None
) -> list[str]:
    """``harness mission`` for a script on the channel at ``address`` (per vehicle, or the swarm's: -1)."""
    named = ["--name", name] if name else []
    head = [python, "-m", "harness.cli", "mission", "--channel", address, f"--vehicle={vehicle}"]
    return [*head, *named, str(script), "--", *args]


def peer_name(script_name: str) -> str:
    return f"{SWARM_PEER_PREFIX}{script_name}"


def swarm_exit(exits: Sequence[Any]) -> Any | None:
    """The swarm mission's ``MissionExit`` among the channel's (None while it runs)."""
    for e in exits:
        if e.vehicle == SWARM_VEHICLE and str(e.peer).startswith(SWARM_PEER_PREFIX):
            return e
    return None
