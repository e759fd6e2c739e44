"""The script contract (issue 11): any MAVLink client library, unmodified, reaches its own vehicle on sim time,
in a run no other run can touch, and the same seed flies the same flight."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from harness.pytest_plugin import RunRecord, VehicleRecord, run_harness
from harness.simclock import shim
from tests.run.flights import MISSIONS

pytestmark = pytest.mark.sim
needs_shim = pytest.mark.skipif(
    shim.compiler() is None,
    reason="no C compiler: MAVSDK's threads cannot be put on the sim clock (simtime.c), they keep the wall clock",
)


@pytest.mark.parametrize("script", ["pymavlink_takeoff.py", "dronekit_takeoff.py"])
def test_socket_scripts_reach_their_own_vehicle_on_sim_time(tmp_path: Path, script: str) -> None:
    """Synchronous pymavlink (``udpin:0.0.0.0:14540``, ``recv_match`` with timeouts, ``time.sleep`` polling)
    and DroneKit (its reader thread on pymavlink's ``select`` loop) on 3 vehicles: each talks to system
    index + 1, reads 10 Hz ATTITUDE on sim time (the scripts check ~20 in 2 s), arms, takes off in PX4's
    TAKEOFF mode, lands and exits 0."""
    if script.startswith("dronekit"):
        pytest.importorskip("dronekit", reason="dronekit2 is in the dev extra")
    run = run_harness(tmp_path / "run", MISSIONS / script, vehicles=3, duration_s=120)
    assert run.ok, run.message
    for i in range(3):
        v = run.vehicle(i)
        out = run.mission_output(i)
        assert v.mission_exit_code == 0
        assert f"system {i + 1}" in out, out
        assert "landed and disarmed" in out, out
        assert 2.0 < v.max_altitude_m < 4.0  # PX4's default takeoff altitude, 2.5 m
        assert v.landed


def _liftoff_s(v: VehicleRecord) -> float:
    z0 = v.track[0]["pos_ned_m"][2]
    return next(m["t_s"] for m in v.track if z0 - m["pos_ned_m"][2] > 0.3)


def _three_runs(
    tmp_path: Path,
    script: str,
    duration_s: float,
    vehicles: int = 2,
    seed: int = 5,
    swarm: bool = False,
    args: tuple[str, ...] = (),
) -> list[RunRecord]:
    """Max speed twice and x5 (``benchmarks/determinism.py --busy 8`` adds busy processes beside the runs).
    ``swarm``: the script commands every vehicle (``--swarm-mission``)."""
    runs = []
    for k, speed in enumerate([None, None, 5.0]):
        run = run_harness(
            tmp_path / f"run-{k}",
            [] if swarm else MISSIONS / script,
            vehicles=vehicles,
            seed=seed,
            speed=speed,
            duration_s=duration_s,
            args=args,
            extra=["--swarm-mission", str(MISSIONS / script)] if swarm else (),
        )
        assert run.summary["status"] in ("ok", "failed"), run.message  # a duration limit may end it mid-mission
        assert all(run.vehicle(i).track for i in range(vehicles)), run.message
        runs.append(run)
    return runs


def _assert_byte_identical(runs: list[RunRecord], vehicles: int, label: str) -> None:
    print(f"FIGURE {label}: lift-off {[[_liftoff_s(r.vehicle(i)) for r in runs] for i in range(vehicles)]} s")
    for i in range(vehicles):
        tracks = [[(m["t_s"], m["pos_ned_m"]) for m in r.vehicle(i).track] for r in runs]
        assert [t for t, _ in tracks[0]] == [t for t, _ in tracks[1]] == [t for t, _ in tracks[2]]
        for k in (1, 2):
            diff = next(((t, p, q) for (t, p), (_, q) in zip(tracks[0], tracks[k], strict=True) if p != q), None)
            assert diff is None, f"vehicle {i}, run {k}: first differs at t={diff[0]} s: {diff[1]} vs {diff[2]}"


@pytest.mark.parametrize("script", ["pymavlink_takeoff.py", "dronekit_takeoff.py"])
def test_same_seed_same_flight_byte_identical_for_socket_scripts(tmp_path: Path, script: str) -> None:
    """Max speed, max speed under load, and x5: every recorded pose of both vehicles is the same, byte for byte,
    start-up included. (A thread that a loaded machine scheduled late used to see its vehicle's answer one phase
    later, 3 cm apart a few seconds on; streams once kept a grid set by the wall clock.)"""
    if script.startswith("dronekit"):
        pytest.importorskip("dronekit", reason="dronekit2 is in the dev extra")
    _assert_byte_identical(_three_runs(tmp_path, script, duration_s=15), 2, script)


@pytest.mark.parametrize(
    ("script", "duration_s"),
    [
        ("takeoff_and_land.py", 16),  # gRPC API: action and telemetry streams (lift-off at 11.7 s)
        ("mission_rtl.py", 30),  # gRPC API: a waypoint mission driven by its mission_progress and position streams
        ("offboard.py", 30),  # gRPC API: offboard position and velocity setpoints
        ("takeoff_and_land_native.py", 16),  # native API, synchronous calls
        ("square_native.py", 30),  # native API (asyncio): a square mission driven by its telemetry streams
    ],
)
@needs_shim
def test_same_seed_same_flight_byte_identical_for_mavsdk_scripts(
    tmp_path: Path, script: str, duration_s: float
) -> None:
    """MAVSDK of both APIs on the sim clock, its C++ threads included (``harness/simclock/simtime.c``): the same
    seed flies the same flight, byte for byte, at max speed twice and at x5.
    Before: lift-off up to 4 s apart and poses 28 m apart (gRPC, ``mavsdk_server`` on the wall clock), 68 cm
    (native)."""
    _assert_byte_identical(_three_runs(tmp_path, script, duration_s=duration_s), 2, script)


@needs_shim
def test_a_mavsdk_mission_takes_part_only_in_the_phases_that_bring_it_something(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """MAVSDK's threads wait for their sockets; the vehicle tells the channel at which ticks it sent its mission
    MAVLink (END-TICK-AC ``mavlink``), so the mission is left out of the phases that bring it nothing (its telemetry
    comes at 10 Hz or less, phases at 50 Hz) and still takes part in every phase its timers need. The same-seed
    tests above show the flight is the one it flew at every phase."""
    traces = tmp_path / "traces"
    traces.mkdir()
    monkeypatch.setenv("HARNESS_SIMTIME_TRACE_DIR", str(traces))
    run = run_harness(tmp_path / "run", MISSIONS / "takeoff_and_land_native.py", vehicles=1, seed=5, args=("5",))
    assert run.summary["status"] == "ok", run.message
    v = run.vehicle(0)
    assert v.landed and v.max_altitude_m > 2.0 and run.summary["vehicles"][0]["mission_exit_code"] == 0
    lines = (traces / "simclock-0.trace").read_text().splitlines()
    taken = sum(1 for line in lines if line.split(" ", 2)[1:2] == ["close"])
    phases = round(run.summary["sim_time_s"] / 0.02)
    print(f"FIGURE phases taken part in: {taken} of {phases}")
    assert 0.1 * phases < taken < 0.5 * phases


@needs_shim
def test_same_seed_same_flight_byte_identical_for_a_swarm_script(tmp_path: Path) -> None:
    """One gRPC-API script commanding 10 vehicles (``missions/formation.py``: a ``System`` each, telemetry streams
    and offboard velocity at 10 Hz): byte for byte, at max speed twice and at x5, to 30 s (the V formed up).
    Before: MAVLink to vehicles 1..9 was never settled and a seventh blocking call waited behind six for a free
    pool thread; lift-offs 11.84 to 11.92 s from run to run, tracks apart from 11.2 s."""
    runs = _three_runs(tmp_path, "formation.py", duration_s=30, vehicles=10, seed=4, swarm=True, args=("5",))
    _assert_byte_identical(runs, 10, "formation.py")


def test_two_runs_started_together_never_share_a_port(tmp_path: Path) -> None:
    """Five times, two runs with missions started in the same instant: both succeed, on different ports."""
    for k in range(5):
        procs = []
        for j in range(2):
            out = tmp_path / f"run-{k}-{j}"
            cmd = [sys.executable, "-m", "harness.cli", "run", "--out", str(out), "--duration", "60"]
            cmd += ["--mission", str(MISSIONS / "pymavlink_takeoff.py")]
            procs.append((out, subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)))
        summaries = []
        for out, proc in procs:
            _, err = proc.communicate(timeout=300)
            assert proc.returncode == 0, err[-2000:]
            summaries.append(json.loads((out / "summary.json").read_text()))
        a, b = summaries
        print(
            f"FIGURE trial {k}: api {a['api_port_base']} / {b['api_port_base']}, gcs {a['gcs_port']} / {b['gcs_port']}"
        )
        assert a["api_port_base"] != b["api_port_base"] and a["gcs_port"] != b["gcs_port"], (a, b)
        assert all(v["mission_exit_code"] == 0 for s in summaries for v in s["vehicles"])
