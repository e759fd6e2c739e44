"""The base layer (harness/core): the clock, geodesy, and the typed kinds files and the CLI carry as text."""

from __future__ import annotations

import json
import math
import struct
import time
from pathlib import Path

import pytest

from harness.autopilot.api import Failsafe
from harness.autopilot.sitl import TlogWriter
from harness.core.clock import WALL, Clock, ManualClock
from harness.core.errors import ScenarioError
from harness.core.geo import EARTH_RADIUS_M, WGS84_A_M, GeoRef, flat_offset_m, flat_point
from harness.net.model import NetworkKind
from harness.run.result import RunResult, RunStatus, VehicleSummary
from harness.scenario.plan import AutopilotPlacement, LaunchPlan


def test_manual_clock_moves_only_forward_and_sleeps_by_jumping() -> None:
    clock = ManualClock(start_ns=5, epoch_unix_ns=1_700_000_000_000_000_000)
    clock.sleep_ns(10)
    clock.sleep_ns(-3)  # a negative sleep returns at once, as time.sleep(0) would
    assert clock.now_ns() == 15
    clock.advance(5)
    clock.advance_to(40)
    assert clock.now_ns() == 40 and clock.unix_ns() == 1_700_000_000_000_000_040
    with pytest.raises(ValueError, match="backwards"):
        clock.advance_to(39)
    with pytest.raises(ValueError, match="backwards"):
        clock.advance(-1)
    assert clock.now_ns() == 40


def test_the_wall_clock_reads_and_waits_real_time() -> None:
    t0 = time.monotonic_ns()
    a = WALL.now_ns()
    WALL.sleep_ns(20_000_000)
    b = WALL.now_ns()
    assert t0 <= a and b - a >= 20_000_000 and time.monotonic_ns() - t0 >= 20_000_000
    assert abs(WALL.unix_ns() - time.time_ns()) < 1_000_000_000


def test_an_injected_clock_stamps_the_tlog(tmp_path: Path) -> None:
    clock: Clock = ManualClock(epoch_unix_ns=1_600_000_000_123_456_000)
    tlog = TlogWriter(tmp_path / "v.tlog", clock=clock)
    tlog.write(b"\xfd\x00")
    assert isinstance(clock, ManualClock)
    clock.advance(1_000_000)  # 1 ms later
    tlog.write(b"\xfd\x01")
    tlog.close()
    data = (tmp_path / "v.tlog").read_bytes()
    first, second = struct.unpack_from(">Q", data, 0)[0], struct.unpack_from(">Q", data, 10)[0]
    assert (first, second) == (1_600_000_000_123_456, 1_600_000_000_124_456)


def test_flat_offsets_invert_and_match_the_projection_nearby() -> None:
    lat0, lon0 = 47.397742, 8.545594
    dn, de = flat_offset_m(lat0, lon0, lat0 + 0.001, lon0 - 0.002)
    assert dn == pytest.approx(math.radians(0.001) * EARTH_RADIUS_M)
    assert flat_point(lat0, lon0, dn, de) == pytest.approx((lat0 + 0.001, lon0 - 0.002), abs=1e-12)
    ref = GeoRef(lat0, lon0, 488.0)
    n, e, d = ref.to_ned(lat0 + 0.001, lon0 - 0.002, 500.0)
    assert (n, e) == pytest.approx((dn, de), abs=0.05) and d == pytest.approx(-12.0)
    assert ref.to_geo(n, e, d) == pytest.approx((lat0 + 0.001, lon0 - 0.002, 500.0), abs=1e-9)
    assert flat_offset_m(lat0, lon0, lat0 + 1.0, lon0, WGS84_A_M)[0] == pytest.approx(111_319.49, abs=0.01)


def test_kinds_serialise_as_the_text_files_always_held() -> None:
    assert json.dumps([Failsafe.GEOFENCE, Failsafe.NONE, RunStatus.INTERRUPTED]) == '["geofence", "", "interrupted"]'
    result = RunResult(RunStatus.OK, 10.0, 2.0, [VehicleSummary(0, "hover.py")], [])
    assert json.loads(json.dumps(result.to_json()))["status"] == "ok" and result.exit_code == 0
    assert RunResult(RunStatus.INTERRUPTED, 1.0, 1.0, [], []).exit_code == 130


def test_a_plan_takes_kinds_as_text_and_refuses_a_bad_one_in_one_line(tmp_path: Path) -> None:
    plan = LaunchPlan(vehicles=1, out=tmp_path, network="builtin", autopilots="process", gps="standalone")  # type: ignore[arg-type]
    assert plan.network is NetworkKind.BUILTIN and plan.autopilots is AutopilotPlacement.PROCESS
    assert plan.gps == "standalone"
    with pytest.raises(ScenarioError) as info:
        LaunchPlan(vehicles=1, out=tmp_path, network="wifi")  # type: ignore[arg-type]
    assert str(info.value) == "network: expected one of 'none', 'builtin', 'ns3', got 'wifi'"
