"""Each firmware's SITL defaults: where its vehicles start (ArduPilot at CMAC, spaced as ``sim_vehicle.py
--auto-offset-line 90,10`` spaces them; PX4 at its home, moved by ``PX4_HOME_*``) and PX4's speed factor."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest

from harness.autopilot.firmware import Firmware
from harness.cli import _plan_from_args, build_parser
from harness.core.errors import ScenarioError
from harness.scenario.config import load_scenario
from harness.scenario.plan import LaunchPlan
from harness.scenario.sitl_defaults import CMAC, PX4_HOME

AP = (Firmware.ARDUPILOT,)


def plan_of(argv: list[str]) -> LaunchPlan:
    a = build_parser().parse_args(argv)
    return _plan_from_args(a)


def test_ardupilot_vehicles_start_at_cmac_spaced_10_m_east(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("PX4_HOME_LAT", raising=False)
    plan = LaunchPlan(vehicles=3, out=Path("x"), firmware=AP)
    assert plan.origin == CMAC == (-35.363261, 149.165230, 584.0) and plan.heading_deg == 353.0
    assert plan.spawn_ned_m == ((0.0, 0.0, 0.0), (0.0, 10.0, 0.0), (0.0, 20.0, 0.0))
    px4 = LaunchPlan(vehicles=3, out=Path("x"))
    assert px4.origin == PX4_HOME and px4.heading_deg == 0.0 and px4.spawn_ned_m is None  # the physics' grid
    # both overridable as before
    mine = LaunchPlan(vehicles=1, out=Path("x"), firmware=AP, origin=(1.0, 2.0, 3.0), spawn_ned_m=((5.0, 0.0, 0.0),))
    assert mine.origin == (1.0, 2.0, 3.0) and mine.spawn_ned_m == ((5.0, 0.0, 0.0),)


def test_command_line_firmware_moves_a_scenario_to_cmac(tmp_path: Path) -> None:
    (tmp_path / "s.toml").write_text("vehicles = 2\n")
    plan = load_scenario(tmp_path / "s.toml", firmware=AP)
    assert plan.origin == CMAC and plan.spawn_ned_m == ((0.0, 0.0, 0.0), (0.0, 10.0, 0.0))
    (tmp_path / "w.toml").write_text('[world]\nalt_amsl_m = 600.0\n[vehicles]\ncount = 1\nfirmware = "ardupilot"\n')
    assert load_scenario(tmp_path / "w.toml").origin == (CMAC[0], CMAC[1], 600.0)  # the rest: the firmware's
    assert load_scenario(tmp_path / "s.toml").origin == PX4_HOME


def test_px4_home_and_speed_factor_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PX4_HOME_LAT", "28.452386")
    monkeypatch.setenv("PX4_HOME_LON", "-13.867138")
    monkeypatch.setenv("PX4_HOME_ALT", "28.5")
    monkeypatch.setenv("PX4_SIM_SPEED_FACTOR", "5")
    plan = plan_of(["run", "--vehicles", "1"])
    assert plan.origin == (28.452386, -13.867138, 28.5) and plan.speed == 5.0
    assert plan_of(["run", "--vehicles", "1", "--speed", "max"]).speed is None  # --speed wins
    assert plan_of(["run", "--vehicles", "1", "--speed", "2"]).speed == 2.0
    assert plan_of(["run", "--vehicles", "1", "--firmware", "ardupilot"]).origin == CMAC  # PX4's variables
    monkeypatch.delenv("PX4_HOME_ALT")
    assert plan_of(["run", "--vehicles", "1"]).origin == (28.452386, -13.867138, PX4_HOME[2])
    monkeypatch.delenv("PX4_SIM_SPEED_FACTOR")
    assert plan_of(["run", "--vehicles", "1"]).speed is None
    assert plan_of(["sitl", "--vehicles", "1"]).speed == 1.0


@pytest.mark.parametrize(
    ("name", "value", "why"),
    [
        ("PX4_HOME_LAT", "north", "PX4_HOME_LAT: expected a number, got 'north'"),
        ("PX4_HOME_LAT", "95", "is not a latitude/longitude"),
        ("PX4_SIM_SPEED_FACTOR", "0", "PX4_SIM_SPEED_FACTOR: must be > 0"),
        ("PX4_SIM_SPEED_FACTOR", "nan", "PX4_SIM_SPEED_FACTOR: must be finite"),
    ],
)
def test_bad_environment_is_one_line(monkeypatch: pytest.MonkeyPatch, name: str, value: str, why: str) -> None:
    monkeypatch.setenv(name, value)
    with pytest.raises(ScenarioError, match=why.replace("(", r"\(")):
        plan_of(["run", "--vehicles", "1"])
    env = {name: value, "PATH": "/usr/bin:/bin"}
    proc = subprocess.run(
        [sys.executable, "-m", "harness.cli", "run", "--vehicles", "1", "--duration", "1"],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert proc.returncode != 0 and "Traceback" not in proc.stderr and why.split(":")[0] in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr


def test_cmac_spacing_matches_sim_vehicle_offsets() -> None:
    """sim_vehicle.py: instance i at d = 10 i m along bearing 90: east = d sin(90°), north = d cos(90°)."""
    plan = LaunchPlan(vehicles=4, out=Path("x"), firmware=AP)
    assert plan.spawn_ned_m is not None
    for i, (n, e, d) in enumerate(plan.spawn_ned_m):
        assert math.isclose(e, 10.0 * i) and abs(n) < 1e-9 and d == 0.0


def test_sim_parameters_in_a_scenario(tmp_path: Path) -> None:
    """SIM_* are vehicle parameters a scenario may set (they act from the first tick); the pace is ``speed``."""
    (tmp_path / "m.toml").write_text('[vehicles]\ncount = 1\nfirmware = "ardupilot"\nparams = { SIM_WIND_SPD = 5 }\n')
    assert load_scenario(tmp_path / "m.toml").params[0] == {"SIM_WIND_SPD": 5.0}
    (tmp_path / "s.toml").write_text("[vehicles]\ncount = 1\nparams = { SIM_SPEEDUP = 5 }\n")
    with pytest.raises(ScenarioError, match="SIM_SPEEDUP is the run's pace: give it as speed"):
        load_scenario(tmp_path / "s.toml")
