"""Scenario files: valid ones become plans; every error is one line naming the file and the field."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from harness.core.errors import ScenarioError
from harness.scenario.config import load_scenario

ROOT = Path(__file__).resolve().parents[2]


def write(tmp_path: Path, text: str) -> Path:
    (tmp_path / "m.py").write_text("print('hi')\n")
    path = tmp_path / "s.toml"
    path.write_text(text)
    return path


def test_shipped_example_is_valid() -> None:
    plan = load_scenario(ROOT / "scenarios" / "three_hover.toml")
    assert plan.vehicles == 3 and plan.seed == 7 and plan.speed is None and plan.phase_every == 5
    assert plan.spawn_ned_m == ((0.0, 0.0, 0.0), (0.0, 8.0, 0.0), (0.0, 16.0, 0.0))
    assert plan.wind_ned_m_s == (2.0, 0.0, 0.0) and plan.turbulence == 0.5
    assert all(m is not None and m.script.name == "hover.py" and m.args == ("20",) for m in plan.missions)
    assert plan.params[0] == {"MIS_TAKEOFF_ALT": 10.0}


def test_list_of_vehicles_and_command_line_overrides(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        'seed = 1\n[[vehicles]]\nmission = "m.py"\nspawn_ned_m = [1, 2, 0]\n[[vehicles]]\nparams = { MPC_XY_VEL_MAX = 8 }\n',
    )
    plan = load_scenario(path, seed=9, duration_s=12.0)
    assert plan.vehicles == 2 and plan.seed == 9 and plan.duration_s == 12.0
    assert plan.gps == "px4-sitl" and plan.sensor_noise  # the defaults
    assert load_scenario(write(tmp_path, 'vehicles = 1\n[sensors]\ngps = "standalone"\n')).gps == "standalone"
    assert plan.missions[1] is None and plan.spawn_ned_m is not None and plan.spawn_ned_m[0] == (1.0, 2.0, 0.0)


@pytest.mark.parametrize(
    ("text", "field", "why"),
    [
        ("vehicles = 1\nsped = 2\n", "sped", "unknown key (did you mean 'speed'?)"),
        ("vehicles = 1\n[rates]\ntick_hz = 'fast'\n", "rates.tick_hz", "expected a number, got str"),
        ("[[vehicles]]\nmission = 'missing.py'\n", "vehicles[0].mission", "file missing.py does not exist"),
        ("vehicles = 1\n[rates]\nphysics_hz = -1000\n", "rates.physics_hz", "must be > 0"),
        ("vehicles = 1\nspeed = 'warp'\n", "speed", "expected a number, got str"),
        ("vehicles = 0\n", "vehicles", "must be >= 1"),
        ("vehicles = 1\n[rates]\nphase_every = 2.5\n", "rates.phase_every", "expected an integer"),
        ("vehicles = 1\n[network]\nmodel = 'wifi'\n", "network.model", "must be 'builtin', 'ns3' or 'none'"),
        ("[[vehicles]]\nspawn_ned_m = [1, 2]\n", "vehicles[0].spawn_ned_m", "expected [north, east, down]"),
        ("vehicles = 1\n[wind]\nturbulence = 'hurricane'\n", "wind.turbulence", "expected a number or one of"),
        ("vehicles = 1\n[sensors]\ngps = 'rtk-fixed'\n", "sensors.gps", "expected one of ['px4-sitl', 'standalone']"),
        ("vehicles = 1\n[sensors]\nnoise = 'off'\n", "sensors.noise", "expected true or false"),
    ],
)
def test_errors_name_file_and_field_in_one_line(tmp_path: Path, text: str, field: str, why: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: {field}: ")
    assert why in message


def test_cli_prints_one_line_without_traceback(tmp_path: Path) -> None:
    path = write(tmp_path, "vehicles = 1\n[rates]\ntick_hz = -5\n")
    proc = subprocess.run(
        [sys.executable, "-m", "harness.cli", "run", str(path)], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"harness: {path}: rates.tick_hz: must be > 0, got -5"


def test_missing_file_and_bad_toml(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match="does not exist"):
        load_scenario(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("vehicles = [\n")
    with pytest.raises(ScenarioError, match="not valid TOML"):
        load_scenario(bad)


def test_firmware_per_vehicle_for_all_and_refused_names(tmp_path: Path) -> None:
    from harness.autopilot.firmware import Firmware

    mixed = write(tmp_path, '[[vehicles]]\nfirmware = "ardupilot"\n[[vehicles]]\n[[vehicles]]\nfirmware = "PX4"\n')
    plan = load_scenario(mixed)
    assert [plan.firmware_of(i) for i in range(3)] == [Firmware.ARDUPILOT, Firmware.PX4, Firmware.PX4]
    every = write(tmp_path, '[vehicles]\ncount = 2\nfirmware = "ardupilot"\n')
    assert {load_scenario(every).firmware_of(i) for i in range(2)} == {Firmware.ARDUPILOT}
    assert load_scenario(every, firmware=(Firmware.PX4,)).firmware_of(1) is Firmware.PX4  # --firmware wins
    bad = write(tmp_path, '[[vehicles]]\n[[vehicles]]\nfirmware = "apm"\n')
    with pytest.raises(ScenarioError, match=r"s\.toml: vehicles\[1\]\.firmware: unknown firmware 'apm'"):
        load_scenario(bad)
