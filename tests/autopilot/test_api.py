"""Pure parts of the API: PX4 mode mapping, parameter registry, mission validation."""

from __future__ import annotations

import math

from harness.autopilot.api import FlightMode, MavFrame, MissionItem, MissionKind, Result
from harness.autopilot.params import Params, ParamType
from harness.autopilot.validate import check_mission


def test_px4_custom_modes_round_trip() -> None:
    assert FlightMode.HOLD.custom_mode == (4 << 16) | (3 << 24)
    assert FlightMode.OFFBOARD.custom_mode == 6 << 16
    assert FlightMode.MISSION.custom_mode == (4 << 16) | (4 << 24)
    for mode in FlightMode:
        if mode is not FlightMode.ORBIT:
            assert FlightMode.from_custom_mode(mode.custom_mode) is mode
    assert FlightMode.from_px4(4, 0) is FlightMode.HOLD
    assert FlightMode.from_px4(4, 5) is FlightMode.RTL
    assert FlightMode.from_px4(9, 0) is None


def test_params_order_types_and_refusals() -> None:
    p = Params()
    names = p.names()
    assert len(names) == len(set(names)) == len(p)
    assert p.index(names[7]) == 7 and p.definition(7) is not None and p.definition(7).name == names[7]  # type: ignore[union-attr]
    for name in (
        "MIS_TAKEOFF_ALT",
        "RTL_RETURN_ALT",
        "MPC_XY_VEL_MAX",
        "MPC_Z_VEL_MAX_UP",
        "MPC_Z_VEL_MAX_DN",
        "MPC_XY_CRUISE",
        "MPC_LAND_SPEED",
        "NAV_DLL_ACT",
        "COM_OBL_RC_ACT",
        "SYS_FAILURE_EN",
        "GF_ACTION",
        "BAT_N_CELLS",
        "MC_ROLLRATE_P",
        "FLW_TGT_HT",
    ):
        assert name in p, name
    assert p.definition("COM_OBL_RC_ACT").type == ParamType.INT32  # type: ignore[union-attr]
    assert isinstance(p.get("COM_OBL_RC_ACT"), int)
    seen: list[tuple[str, float]] = []
    p.subscribe(lambda n, v: seen.append((n, v)))
    v0 = p.version
    assert p.set("MIS_TAKEOFF_ALT", 12.0).ok
    assert p["MIS_TAKEOFF_ALT"] == 12.0 and p.version == v0 + 1 and seen == [("MIS_TAKEOFF_ALT", 12.0)]
    assert p.set("MIS_TAKEOFF_ALT", math.nan).result == Result.DENIED
    assert p.set("MIS_TAKEOFF_ALT", 1e6).result == Result.DENIED
    assert p.set("COM_OBL_RC_ACT", 2.5).result == Result.DENIED
    assert "unknown" in p.set("NO_SUCH", 1).reason
    assert p["MIS_TAKEOFF_ALT"] == 12.0 and len(seen) == 1


def _wp(seq: int, cmd: int = 16, lat: int = 473977420) -> MissionItem:
    return MissionItem(seq, MavFrame.GLOBAL_RELATIVE_ALT_INT, cmd, x=lat, y=85455940, z=10.0)


def test_mission_validation() -> None:
    assert check_mission([_wp(0, 22), _wp(1), _wp(2, 178), _wp(3, 2000), _wp(4, 21)], MissionKind.MISSION) == ""
    assert "sequence" in check_mission([_wp(1)], MissionKind.MISSION)
    assert check_mission([_wp(0, 31000)], MissionKind.MISSION).startswith("unsupported")
    assert "out of range" in check_mission([_wp(0, lat=950000000)], MissionKind.MISSION)
    assert check_mission([_wp(0, 5003)], MissionKind.FENCE) == ""
    assert check_mission([_wp(0, 16)], MissionKind.FENCE).startswith("unsupported")
    it = MissionItem(0, MavFrame.GLOBAL_RELATIVE_ALT_INT, 16, x=473977420, y=85455940)
    assert abs(it.lat_deg - 47.397742) < 1e-9
    assert MissionItem(0, 6, 16, x=47.5, y=8.5).lat_deg == 47.5


def test_autopilot_satisfies_the_system_protocol() -> None:
    from harness.autopilot.autopilot import Autopilot
    from harness.autopilot.services import System

    ap: System = Autopilot()  # checked structurally by mypy
    s = ap.telemetry.state()
    assert not s.armed and s.mode == FlightMode.HOLD and s.t_ns == 0
