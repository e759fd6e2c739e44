"""Pure logic of the MAVSDK compatibility layer: URL rewriting and API detection."""

from __future__ import annotations

import pytest

from harness.simclock.mavsdk_compat import detect_api, rewrite_url


@pytest.mark.parametrize(
    ("url", "expected"),
    [
        ("udpin://0.0.0.0:14540", "udpin://0.0.0.0:14601"),
        ("udp://:14540", "udp://:14601"),
        ("udp://", "udp://:14601"),
        ("udpin://0.0.0.0:14550", "udpin://0.0.0.0:14550"),
        ("tcpout://127.0.0.1:5760", "tcpout://127.0.0.1:5760"),
        ("tcp://127.0.0.1:14540", "tcp://127.0.0.1:14601"),
        ("serial:///dev/ttyUSB0:57600", "serial:///dev/ttyUSB0:57600"),
    ],
)
def test_standard_port_goes_to_the_vehicle(url: str, expected: str) -> None:
    assert rewrite_url(url, 14601) == expected


def test_detects_the_api_of_a_script() -> None:
    old = "from mavsdk import System\nasync def run():\n    drone = System()\n    await drone.connect()\n"
    new = "from mavsdk import Mavsdk, Configuration\nm = Mavsdk(Configuration.GroundStation)\n"
    new_async = "import mavsdk.asyncio as ma\n"
    assert detect_api(old) == "grpc"
    assert detect_api(new) == "native"
    assert detect_api(new_async) == "native"
    assert detect_api("import time\n") == ""
    assert detect_api("import mavsdk_grpc as mavsdk\n") == "grpc-named"
