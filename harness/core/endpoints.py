"""Where a mission's MAVLink goes: the addresses scripts are written for, mapped to their own vehicle.

Scripts are written for one vehicle on a SITL machine: MAVSDK listens on UDP 14540 (PX4 SITL sends
there), ArduPilot scripts and DroneKit listen on 14550 / 14551 (``sim_vehicle.py``'s outputs) or connect
to TCP 5760 (SITL's SERIAL0), and some connect out to PX4 SITL's own port 14580. In a run every vehicle has
its own ports, and the vehicle *listens*: the mission connects out to it, so no other run can hear or
command it. These pure functions map a script's address to its vehicle's (:class:`VehicleEndpoints`, from the
environment ``harness run`` gives each mission); anything else is left as it is.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass

PX4_API_BASE = 14580
"""PX4 SITL's own MAVLink port for offboard APIs (instance ``i`` listens on ``14580 + i``)."""
GCS_PORT = 14550
"""The ground station's UDP port every vehicle sends to."""
SYSIDS_PER_LINK = 244
"""System ids 1-244 for vehicles (245 is MAVSDK's ground station, 255 QGroundControl's): a MAVLink link (one
ground-station port) shows at most this many vehicles. A run with more (``harness run --cluster``) gives its
vehicles ids modulo this, and no ground-station port sees more than this many consecutive vehicles."""


def sysid(vehicle: int) -> int:
    """Vehicle ``vehicle``'s MAVLink system id: ``vehicle + 1`` in a run of up to 244 vehicles, and unique
    among any 244 consecutive vehicles beyond (ids need only be unique on a link, not in the run)."""
    return vehicle % SYSIDS_PER_LINK + 1


LISTEN_PORTS = frozenset({14540, 14550, 14551})
"""UDP ports a script listens on for its vehicle (``udpin:0.0.0.0:14540``, ``127.0.0.1:14550``)."""
CONNECT_UDP_PORTS = frozenset({14580})
"""UDP ports a script connects out to (PX4 SITL instance 0's MAVLink API port)."""
CONNECT_TCP_PORTS = frozenset({5760})
"""TCP ports a script connects to (ArduPilot SITL's SERIAL0)."""

LISTEN_HELLO = b"HARNESS-LISTEN\n"
"""Datagram a script's redirected listening socket sends its vehicle: 'send me what you send your mission'
(a script that only listens, like pymavlink's ``udpin:`` before it has sent anything, is heard this way)."""

LISTEN_HELLO_WALL = b"HARNESS-LISTEN-WALL\n"
"""Datagram a mission's runtime sends its vehicle from the port its MAVSDK will listen on (``mavsdk_url``):
'greet this port with heartbeats until it answers' (then it is a peer like any that spoke first)."""

SETTLE_PREFIX = b"HARNESS-SETTLE "
"""Datagram a mission's runtime sends its vehicle after the script's MAVLink: the vehicle echoes it once it
has handled everything that arrived before it (one socket, handled in order), answers included."""

_LOCAL_HOSTS = frozenset({"", "0.0.0.0", "127.0.0.1", "localhost", "::", "::1"})
_URL = re.compile(r"^(?P<scheme>[a-z]+)://(?P<host>\[[^\]]*\]|[^:/]*)(?::(?P<port>\d+))?(?P<rest>.*)$")


@dataclass(frozen=True, slots=True)
class VehicleEndpoints:
    """The vehicle's own MAVLink ports on this machine (loopback)."""

    udp_port: int
    tcp_port: int | None = None
    host: str = "127.0.0.1"

    @classmethod
    def from_env(cls, vehicle: int) -> VehicleEndpoints | None:
        """From ``HARNESS_MAVLINK_PORT`` / ``HARNESS_MAVLINK_TCP_PORT`` (None outside a run)."""
        udp = os.environ.get("HARNESS_MAVLINK_PORT")
        if not udp:
            return None
        tcp = os.environ.get("HARNESS_MAVLINK_TCP_PORT")
        return cls(int(udp), int(tcp) if tcp else None)


ENV_VEHICLES = "HARNESS_VEHICLES"
"""Every vehicle of a run, for a swarm mission (a JSON list; ``harness.run.swarm`` writes it)."""


def team_from_env() -> list[VehicleEndpoints]:
    """The ports of every vehicle a swarm mission commands (``HARNESS_VEHICLES``); empty outside a swarm mission.

    Raises ``ValueError`` with what is wrong when the variable is not the list the launcher writes."""
    text = os.environ.get(ENV_VEHICLES)
    if not text:
        return []
    try:
        items = json.loads(text)
        return [
            VehicleEndpoints(int(v["udp_port"]), None if v.get("tcp_port") is None else int(v["tcp_port"]))
            for v in items
        ]
    except (ValueError, TypeError, KeyError) as e:
        raise ValueError(f"{ENV_VEHICLES} is not a list of vehicles with udp_port and tcp_port ({e})") from None


def team_member(scheme: str, host: object, port: int, team: Sequence[VehicleEndpoints]) -> VehicleEndpoints | None:
    """The vehicle of ``team`` that a swarm mission addresses at ``(host, port)`` over ``scheme`` (``udp`` or
    ``tcp``): its own port, given in ``HARNESS_VEHICLES``; None for any other address."""
    if not is_local(host):
        return None
    for ep in team:
        if (ep.udp_port if scheme == "udp" else ep.tcp_port) == port:
            return ep
    return None


def is_local(host: object) -> bool:
    return isinstance(host, str) and host in _LOCAL_HOSTS


def udp_listen_redirected(host: object, port: int) -> bool:
    """Whether binding ``(host, port)`` is a script listening for its vehicle."""
    return port in LISTEN_PORTS and is_local(host)


def udp_destination(host: object, port: int, ep: VehicleEndpoints) -> tuple[str, int] | None:
    """The vehicle's address for a datagram a script sends to ``(host, port)``; None: not the vehicle."""
    if is_local(host) and (port in CONNECT_UDP_PORTS or port in LISTEN_PORTS):
        return (ep.host, ep.udp_port)
    return None


def tcp_destination(host: object, port: int, ep: VehicleEndpoints) -> tuple[str, int] | None:
    """The vehicle's address for a TCP connection to ``(host, port)``; None: not the vehicle."""
    if ep.tcp_port is not None and is_local(host) and port in CONNECT_TCP_PORTS:
        return (ep.host, ep.tcp_port)
    return None


def mavsdk_url(url: str, ep: VehicleEndpoints, listen_port: Callable[[], int] | None = None) -> str:
    """A MAVSDK connection URL for the vehicle (``udpin://0.0.0.0:14540`` → ``udpin://127.0.0.1:L``).

    The listening forms and ``udpout`` to the standard ports become ``udpin`` on a port ``L`` that
    ``listen_port`` reserved and announced to the vehicle (:data:`LISTEN_HELLO_WALL`): the vehicle sends
    there, MAVSDK listens there. Not ``udpout``: MAVSDK's ``udpout`` binds port 0 with ``SO_REUSEADDR``, and
    Linux gives such a socket a port another one already holds — two missions of a swarm then share a port
    and one hears the other's vehicle (``docs/tree.md``). Without ``listen_port``: ``udpout`` to the
    vehicle's port. Other URLs (serial, other hosts and ports) are left as they are.
    """
    m = _URL.match(url)
    if m is None:
        return url
    scheme, host, port_text = m.group("scheme"), m.group("host").strip("[]"), m.group("port")
    port = int(port_text) if port_text else None
    to_vehicle = (scheme in ("udp", "udpin") and (port is None or udp_listen_redirected(host, port))) or (
        scheme == "udpout" and port is not None and udp_destination(host, port, ep) is not None
    )
    if to_vehicle:
        return f"udpin://127.0.0.1:{listen_port()}" if listen_port else f"udpout://{ep.host}:{ep.udp_port}"
    if scheme in ("tcp", "tcpout") and port is not None and tcp_destination(host, port, ep):
        return f"tcpout://{ep.host}:{ep.tcp_port}"
    return url


def team_mavsdk_url(
    url: str, team: Sequence[VehicleEndpoints], listen_port: Callable[[VehicleEndpoints], int]
) -> tuple[str, VehicleEndpoints | None]:
    """A swarm mission's MAVSDK URL for one of its vehicles, and that vehicle (None: not one of them).

    ``udpout://127.0.0.1:P`` to vehicle ``i``'s own port (``HARNESS_VEHICLES``' ``mavsdk_url``) becomes ``udpin``
    on a port ``listen_port(vehicle)`` reserved and announced to it, as a one-vehicle mission's does
    (:func:`mavsdk_url`): the vehicle knows it as a peer on sim time from the start. TCP URLs stay as they are."""
    m = _URL.match(url)
    if m is None or m.group("port") is None:
        return url, None
    scheme, host, port = m.group("scheme"), m.group("host").strip("[]"), int(m.group("port"))
    if scheme in ("tcp", "tcpout"):
        return url, team_member("tcp", host, port, team)
    if scheme != "udpout":  # MAVSDK's udp:// and udpin:// listen: not a vehicle's port
        return url, None
    ep = team_member("udp", host, port, team)
    if ep is None:
        return url, None
    return f"udpin://127.0.0.1:{listen_port(ep)}", ep
