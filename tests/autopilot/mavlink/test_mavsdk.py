"""Smoke test with the real MAVSDK (native ``mavsdk`` 4.x, its C++ core over ctypes) as the ground station:
the vehicle flies in-process (Autopilot + test quad model at up to 4x real time) and MAVSDK, listening on the
vehicle's API port like an unmodified script (``udpin://0.0.0.0:PORT``), connects, waits for health, reads
the version and parameters, flies a mission with return to launch, then takeoff, offboard velocity, land."""

from __future__ import annotations

import math
import socket
from collections.abc import Callable, Iterator

import pytest

from harness.core.clock import real_monotonic_ns, real_sleep
from tests.autopilot.mavlink.conftest import Rig

mavsdk = pytest.importorskip("mavsdk")
from mavsdk.plugins.action import Action  # noqa: E402
from mavsdk.plugins.info import Info  # noqa: E402
from mavsdk.plugins.mission import Mission, MissionItem, MissionPlan  # noqa: E402
from mavsdk.plugins.offboard import Offboard, VelocityNedYaw  # noqa: E402
from mavsdk.plugins.param import Param  # noqa: E402
from mavsdk.plugins.telemetry import Telemetry  # noqa: E402


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait(cond: Callable[[], bool], timeout_s: float, what: str) -> None:
    end = real_monotonic_ns() + int(timeout_s * 1e9)
    while real_monotonic_ns() < end:
        if cond():
            return
        real_sleep(0.1)
    raise AssertionError(f"MAVSDK: {what} not within {timeout_s} s")


class _Port:
    def __init__(self, port: int) -> None:
        self.port = port


@pytest.fixture
def mavsdk_rig() -> Iterator[tuple[Rig, object]]:
    port = _free_udp_port()
    rig = Rig(_Port(port), speed=4.0).start()  # type: ignore[arg-type]
    drone = mavsdk.Mavsdk(mavsdk.Configuration.create_with_component_type(mavsdk.ComponentType.GROUND_STATION))
    try:
        assert drone.add_any_connection(f"udpin://0.0.0.0:{port}") == mavsdk.ConnectionResult.SUCCESS
        system = drone.first_autopilot(5.0)
        assert system is not None, "MAVSDK did not discover the autopilot"
        yield rig, system
    finally:
        drone.destroy()
        rig.stop()


@pytest.mark.timeout(120)
def test_mavsdk_health_params_mission_offboard(mavsdk_rig: tuple[Rig, object]) -> None:
    rig, system = mavsdk_rig
    tel, act, info, par = Telemetry(system), Action(system), Info(system), Param(system)
    mission, offboard = Mission(system), Offboard(system)

    def healthy() -> bool:
        h = tel.health()
        return bool(h.is_global_position_ok and h.is_home_position_ok and h.is_armable and h.is_local_position_ok)

    _wait(healthy, 10.0, "health ok (global, local, home, armable)")
    v = info.get_version()
    assert (v.flight_sw_major, v.flight_sw_minor) == (1, 15)
    params = par.get_all_params()
    assert len(params.int_params) + len(params.float_params) == len(rig.ap.params)
    par.set_param_float("MIS_TAKEOFF_ALT", 4.0)
    assert par.get_param_float("MIS_TAKEOFF_ALT") == 4.0
    assert rig.ap.params["MIS_TAKEOFF_ALT"] == 4.0

    home = tel.home()
    nan = math.nan
    legs = [(2e-5, 0.0), (2e-5, 3e-5)]
    items = [
        MissionItem(home.latitude_deg + dn, home.longitude_deg + de, 5.0, 3.0, True, nan, nan,
                    MissionItem.CameraAction.NONE, nan, nan, 1.0, nan, nan, MissionItem.VehicleAction.NONE)
        for dn, de in legs
    ]  # fmt: skip
    mission.set_return_to_launch_after_mission(True)
    mission.upload_mission(MissionPlan(items))
    act.arm()
    mission.start_mission()
    far = [0.0]

    def finished() -> bool:
        far[0] = max(far[0], math.hypot(rig.sim.pos[0], rig.sim.pos[1]))
        return bool(mission.is_mission_finished())

    _wait(finished, 60.0, "mission finished")
    assert far[0] > 2.5, "it flew the legs"
    _wait(lambda: not tel.in_air(), 30.0, "landed after return")
    assert math.hypot(rig.sim.pos[0], rig.sim.pos[1]) < 1.5, "returned home"
    _wait(lambda: not tel.armed(), 20.0, "auto-disarm")

    act.arm()
    act.takeoff()
    _wait(lambda: -rig.sim.pos[2] > 3.5, 20.0, "takeoff to MIS_TAKEOFF_ALT")
    n0 = rig.sim.pos[0]
    offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, 0.0))
    offboard.start()
    offboard.set_velocity_ned(VelocityNedYaw(1.0, 0.0, 0.0, 0.0))
    _wait(lambda: rig.sim.pos[0] - n0 > 2.0, 10.0, "offboard velocity north")
    offboard.stop()
    act.land()
    _wait(lambda: not tel.in_air(), 30.0, "landed")
    c = rig.server.counters()
    assert c.malformed == 0 and c.handler_errors == 0
    assert c.commands.get("ACCEPTED", 0) >= 8
