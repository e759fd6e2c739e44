"""Pure logic of the MAVSDK compatibility layer: URL rewriting and API detection."""

from __future__ import annotations

import socket

import pytest

from harness.core.endpoints import VehicleEndpoints, mavsdk_url
from harness.simclock.mavsdk_compat import detect_api

EP = VehicleEndpoints(udp_port=14601, tcp_port=15761)


@pytest.mark.parametrize(
    ("url", "expected"),
    [
        ("udpin://0.0.0.0:14540", "udpout://127.0.0.1:14601"),
        ("udp://:14540", "udpout://127.0.0.1:14601"),
        ("udp://", "udpout://127.0.0.1:14601"),
        ("udpin://0.0.0.0:14550", "udpout://127.0.0.1:14601"),
        ("udpout://127.0.0.1:14580", "udpout://127.0.0.1:14601"),
        ("udpin://0.0.0.0:14999", "udpin://0.0.0.0:14999"),
        ("udpout://10.0.0.7:14580", "udpout://10.0.0.7:14580"),
        ("tcpout://127.0.0.1:5760", "tcpout://127.0.0.1:15761"),
        ("tcp://localhost:5760", "tcpout://127.0.0.1:15761"),
        ("tcpout://127.0.0.1:5762", "tcpout://127.0.0.1:5762"),
        ("serial:///dev/ttyUSB0:57600", "serial:///dev/ttyUSB0:57600"),
    ],
)
def test_script_addresses_go_to_the_vehicle(url: str, expected: str) -> None:
    assert mavsdk_url(url, EP) == expected


@pytest.mark.parametrize("url", ["udpin://0.0.0.0:14540", "udp://", "udpout://127.0.0.1:14580"])
def test_with_an_announced_port_mavsdk_listens_there(url: str) -> None:
    """In a run MAVSDK listens on a port the mission's runtime reserved and announced to the vehicle (its
    ``udpout`` would bind port 0 with SO_REUSEADDR, which Linux may give two missions alike)."""
    assert mavsdk_url(url, EP, lambda: 40123) == "udpin://127.0.0.1:40123"
    assert mavsdk_url("udpin://0.0.0.0:14999", EP, lambda: 40123) == "udpin://0.0.0.0:14999"


def test_port_zero_with_so_reuseaddr_is_the_trap_the_announced_port_avoids() -> None:
    """Why: with SO_REUSEADDR, binding port 0 can give a port another SO_REUSEADDR socket holds (Linux); a
    socket bound without it is never given away. The reservation binds without it."""
    held = []
    try:
        for _ in range(2000):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            held.append(s)
            s.bind(("127.0.0.1", 0))
        plain = {s.getsockname()[1] for s in held}
        assert len(plain) == len(held)  # without the option: never shared
        shared = []
        for _ in range(2000):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            held.append(s)
            s.bind(("0.0.0.0", 0))
            shared.append(s.getsockname()[1])
        assert not plain & set(shared), "a port held without SO_REUSEADDR was given to another socket"
    finally:
        for s in held:
            s.close()


def test_without_a_tcp_port_tcp_stays() -> None:
    assert mavsdk_url("tcpout://127.0.0.1:5760", VehicleEndpoints(14601)) == "tcpout://127.0.0.1:5760"


def test_detects_the_api_of_a_script() -> None:
    old = "from mavsdk import System\nasync def run():\n    drone = System()\n    await drone.connect()\n"
    new = "from mavsdk import Mavsdk, Configuration\nm = Mavsdk(Configuration.GroundStation)\n"
    new_async = "import mavsdk.asyncio as ma\n"
    assert detect_api(old) == "grpc"
    assert detect_api(new) == "native"
    assert detect_api(new_async) == "native"
    assert detect_api("import time\n") == ""
    assert detect_api("import mavsdk_grpc as mavsdk\n") == "grpc-named"
