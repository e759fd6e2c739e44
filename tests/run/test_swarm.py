"""A swarm from one script (issue 13): ``harness run --swarm-mission`` / ``[swarm] mission``, ``HARNESS_VEHICLES``."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from harness.autopilot.firmware import Firmware
from harness.core.errors import ScenarioError
from harness.record.world import read_topics
from harness.run import swarm
from harness.scenario.config import load_scenario

MISSIONS = Path(__file__).resolve().parents[2] / "missions"


def _harness_run(*argv: str, timeout: float = 900) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "harness.cli", "run", "--no-progress", *argv],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_vehicles_variable_round_trips_and_hides_the_one_vehicle_variables() -> None:
    fw = (Firmware.PX4, Firmware.ARDUPILOT, Firmware.PX4)
    team = swarm.swarm_vehicles(3, 20000, lambda i: fw[i], lambda i: 30000 + 10 * i)
    env = swarm.swarm_env({"HARNESS_VEHICLE": "0", "HARNESS_MAVLINK_PORT": "1", "PATH": "/bin"}, team)
    assert "HARNESS_VEHICLE" not in env and "HARNESS_MAVLINK_PORT" not in env and env["PATH"] == "/bin"
    back = swarm.parse_vehicles(env[swarm.ENV_VEHICLES])
    assert back == team
    assert [v.sysid for v in back] == [1, 2, 3]
    assert back[2].mavsdk_url == "udpout://127.0.0.1:20002" and back[2].pymavlink_url == "udpout:127.0.0.1:20002"
    assert [v.tcp_port for v in back] == [None, 30010, None]


def test_scenario_swarm_key(tmp_path: Path) -> None:
    (tmp_path / "s.py").write_text("")
    (tmp_path / "a.toml").write_text('vehicles = 4\n[swarm]\nmission = "s.py"\nargs = [30]\n')
    plan = load_scenario(tmp_path / "a.toml")
    assert plan.swarm_mission is not None and plan.swarm_mission.script == (tmp_path / "s.py").resolve()
    assert plan.swarm_mission.args == ("30",) and plan.vehicles == 4
    (tmp_path / "b.toml").write_text('vehicles = 4\n[swarm]\nmision = "s.py"\n')
    with pytest.raises(ScenarioError, match=r"swarm\.mision: unknown key \(did you mean 'mission'\?\)"):
        load_scenario(tmp_path / "b.toml")


def test_swarm_mission_sees_every_vehicle_and_its_exit_code_is_everyones(tmp_path: Path) -> None:
    """A plain script (no MAVSDK) sees the run's vehicles and no single vehicle; its exit code decides the run."""
    script = tmp_path / "team.py"
    script.write_text(
        "import json, os, sys, time\n"
        "team = json.loads(os.environ['HARNESS_VEHICLES'])\n"
        "t0 = time.monotonic(); time.sleep(3.0)\n"
        "print(json.dumps({'team': team, 'own': os.environ.get('HARNESS_MAVLINK_PORT'), "
        "'slept': time.monotonic() - t0}))\n"
        "sys.exit(int(sys.argv[1]))\n"
    )
    out = tmp_path / "run"
    proc = _harness_run("--vehicles", "3", "--swarm-mission", str(script), "--out", str(out), "--", "3", timeout=300)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    seen = json.loads((out / "swarm-mission.stdout").read_text())
    summary = json.loads((out / "summary.json").read_text())
    assert [v["udp_port"] for v in seen["team"]] == [summary["api_port_base"] + i for i in range(3)]
    assert seen["own"] is None
    assert seen["slept"] == pytest.approx(3.0, abs=0.021)  # it runs on the sim clock
    assert summary["status"] == "failed" and "exited with 3" in summary["message"]
    assert [v["mission_exit_code"] for v in summary["vehicles"]] == [3, 3, 3]
    assert {v["mission"] for v in summary["vehicles"]} == {str(script)}


def _slot(k: int) -> tuple[float, float]:
    """missions/formation.py's V: slot k relative to the apex (vehicle 0), 8 m apart."""
    row = (k + 1) // 2
    return (-row * 8.0, (-1.0 if k % 2 else 1.0) * row * 8.0 if row else 0.0)


def _cruise(rows: list[tuple[dict[str, Any], ...]]) -> list[tuple[dict[str, Any], ...]]:
    """The longest stretch in which the leader flies north faster than 2.5 m/s."""
    best: list[tuple[dict[str, Any], ...]] = []
    cur: list[tuple[dict[str, Any], ...]] = []
    for r in rows:
        if r[0]["vel_ned_m_s"][0] > 2.5:
            cur.append(r)
        else:
            best, cur = max(best, cur, key=len), []
    return max(best, cur, key=len)


@pytest.mark.sim
def test_one_script_flies_ten_vehicles_in_formation(tmp_path: Path) -> None:
    out = tmp_path / "formation"
    proc = _harness_run(
        "--vehicles", "10", "--swarm-mission", str(MISSIONS / "formation.py"), "--out", str(out), "--", "30"
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert [v["mission_exit_code"] for v in summary["vehicles"]] == [0] * 10
    assert all(v["landed"] and not v["crashed"] for v in summary["vehicles"])
    topics = read_topics(out / "world.mcap")
    rows = list(zip(*(topics[f"/vehicle/{i}/state"] for i in range(10)), strict=False))
    cruise = _cruise(rows)
    assert len(cruise) * 0.02 > 25.0, "the V cruised north for less than 25 s"
    lead_start, lead_end = cruise[0][0]["pos_ned_m"], cruise[-1][0]["pos_ned_m"]
    assert lead_end[0] - lead_start[0] > 75.0
    worst = 0.0
    for r in cruise:
        n0, e0, _ = r[0]["pos_ned_m"]
        for k, s in enumerate(r):
            n, e, d = s["pos_ned_m"]
            sn, se = _slot(k)
            worst = max(worst, math.hypot(n - n0 - sn, e - e0 - se))
            assert d == pytest.approx(-10.0, abs=1.0)
    assert worst < 1.0, f"a vehicle was {worst:.2f} m from its slot in the V while cruising"
