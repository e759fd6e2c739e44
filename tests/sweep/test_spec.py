"""Sweep specs: seeds and --set values expand into a cartesian product, every mistake is one line before anything starts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from harness.core.errors import ScenarioError
from harness.scenario.config import load_scenario, parse_value
from harness.sweep.spec import build_sweep, parse_seeds, run_name, split_values

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "scenarios" / "wind_sweep.toml"


def scenario(tmp_path: Path, text: str = "") -> Path:
    (tmp_path / "m.py").write_text("print('hi')\n")
    path = tmp_path / "s.toml"
    path.write_text('seed = 5\n[vehicles]\ncount = 2\nmission = "m.py"\n' + text)
    return path


def test_seeds_ranges_and_lists() -> None:
    assert parse_seeds("0-3") == (0, 1, 2, 3)
    assert parse_seeds("0,3,7") == (0, 3, 7)
    assert parse_seeds("0-2, 10") == (0, 1, 2, 10)
    for bad, why in [
        ("3-1", "runs backwards"),
        ("a", "not a seed or a range"),
        ("1,1", "given twice"),
        ("-1", "not a"),
    ]:
        with pytest.raises(ScenarioError, match=why):
            parse_seeds(bad)


def test_values_split_outside_brackets_and_parse_as_toml() -> None:
    assert split_values('0, 4.5,[0,0,0],{ A = 1, B = 2 },"a,b",standalone') == [
        "0",
        "4.5",
        "[0,0,0]",
        "{ A = 1, B = 2 }",
        '"a,b"',
        "standalone",
    ]
    assert [parse_value(v) for v in ["4", "4.5", "true", "[1, 2]", '"x"', "standalone"]] == [
        4,
        4.5,
        True,
        [1, 2],
        "x",
        "standalone",
    ]


def test_cartesian_product_in_order_with_stable_names() -> None:
    spec = build_sweep(EXAMPLE, "0-3", ["wind.north_m_s=0,8"])
    assert len(spec.runs) == 8
    assert [(r.seed, r.params()["wind.north_m_s"]) for r in spec.runs[:5]] == [(0, 0), (1, 0), (2, 0), (3, 0), (0, 8)]
    assert spec.runs[5].name == "seed-1_wind.north_m_s-8"
    assert len({r.name for r in spec.runs}) == 8
    # each run's values really reach the plan the run will be built from
    plan = load_scenario(EXAMPLE, sets=[("wind.north_m_s", 8)], seed=3)
    assert plan.wind_ned_m_s == (8.0, 0.0, 0.0) and plan.seed == 3 and plan.vehicles == 2


def test_long_run_names_are_cut_with_a_hash() -> None:
    long = [("vehicles.args", '["' + "x" * 300 + '"]')]
    other = [("vehicles.args", '["' + "x" * 299 + 'y"]')]
    a, b = run_name(1, long), run_name(1, other)
    assert len(a) == 120 and a.startswith("seed-1_vehicles.args-xxx") and a != b and a == run_name(1, long)


def test_two_parameters_and_the_files_seed_by_default(tmp_path: Path) -> None:
    path = scenario(tmp_path)
    spec = build_sweep(path, None, ["vehicles.count=1,3", "vehicles.params.MIS_TAKEOFF_ALT=5,10,15"])
    assert spec.seeds == (5,) and len(spec.runs) == 6
    assert spec.runs[0].sets == (("vehicles.count", "1"), ("vehicles.params.MIS_TAKEOFF_ALT", "5"))
    plan = load_scenario(path, sets=spec.runs[-1].values)
    assert plan.vehicles == 3 and plan.params[2] == {"MIS_TAKEOFF_ALT": 15.0}
    # new tables are created on the way: the file has no [wind]
    assert load_scenario(path, sets=[("wind.east_m_s", 3)]).wind_ned_m_s == (0.0, 3.0, 0.0)


@pytest.mark.parametrize(
    ("sets", "message"),
    [
        (["wind.nort_m_s=1"], "--set wind.nort_m_s=1: {path}: wind.nort_m_s: unknown key (did you mean 'north_m_s'?)"),
        (["wind.north_m_s=0,fast"], "--set wind.north_m_s=fast: {path}: wind.north_m_s: expected a number, got str"),
        (["vehicles.count=2,0"], "--set vehicles.count=0: {path}: vehicles.count: must be >= 1, got 0"),
        (["rates.tick_hz=300"], "--set rates.tick_hz=300: {path}: rates.physics_hz: must be a whole multiple"),
        (["wind.north_m_s"], "--set wind.north_m_s: expected PATH=V1,V2,..."),
        (["wind.north_m_s=1,,2"], "--set wind.north_m_s=1,,2: an empty value"),
        (["wind.north_m_s=1,1"], "--set wind.north_m_s=1,1: a value is given twice"),
        (["wind.north_m_s=1", "wind.north_m_s=2"], "--set wind.north_m_s: given twice"),
        (["vehicles[3].mission=x"], "--set vehicles[3].mission: vehicles has 0 entries in the scenario, no [3]"),
        (["seed.x=1"], "--set seed.x: seed is not a table in the scenario"),
        (["seed=1,2"], "--set seed: not a sweep parameter (sweep seeds with --seeds)"),
        (["out=a,b"], "--set out: not a sweep parameter (the sweep puts each run under --out)"),
        (
            ["network.model=builtin", "network.params.bitrate=1e6"],
            "--set network.model=builtin --set network.params.bitrate=1e6: {path}: network.params.bitrate: unknown parameter",
        ),
        (  # the file has no network: sweeping its parameters would change nothing
            ["network.params.bit_rate_bps=1e6,2e6"],
            "--set network.params.bit_rate_bps: the network model is 'none' in {path}, so network parameters change nothing",
        ),
        (
            ["network.model=builtin,none", "network.params.bit_rate_bps=1e6"],
            "--set network.params.bit_rate_bps: --set network.model=none --set network.params.bit_rate_bps=1e6: "
            "the network model is 'none'",
        ),
    ],
)
def test_mistakes_are_one_line_before_anything_starts(tmp_path: Path, sets: list[str], message: str) -> None:
    path = scenario(tmp_path)
    with pytest.raises(ScenarioError) as err:
        build_sweep(path, "0-1", sets)
    text = str(err.value)
    assert "\n" not in text
    assert text.startswith(message.format(path=path)), text


def test_network_parameters_sweep_with_a_network(tmp_path: Path) -> None:
    path = scenario(tmp_path, '[network]\nmodel = "builtin"\n')
    spec = build_sweep(path, "0", ["network.params.bit_rate_bps=1e6,2e6"])
    assert [r.params() for r in spec.runs] == [
        {"network.params.bit_rate_bps": 1e6},
        {"network.params.bit_rate_bps": 2e6},
    ]


def test_cli_reports_one_line_and_starts_nothing(tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "harness.cli", "sweep", str(EXAMPLE), "--set", "wind.north_m_s=0,x", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"harness: --set wind.north_m_s=x: {EXAMPLE}: wind.north_m_s: expected a number, got str 'x'"
    ]
    assert not out.exists()


def test_harness_run_takes_set_too(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "harness.cli", "run", str(EXAMPLE), "--set", "wind.nort_m_s=4", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"harness: {EXAMPLE}: wind.nort_m_s: unknown key (did you mean 'north_m_s'?)"


@pytest.mark.parametrize(
    ("option", "message"),
    [
        (["--scheduler", "nonsense"], "--scheduler nonsense: expected a Dask scheduler address like tcp://HOST:8786"),
        (["--runs-per-worker", "0"], "--runs-per-worker must be >= 1, got 0"),
        (["--run-timeout", "-1"], "--run-timeout must be > 0 seconds, got -1.0"),
        (["--seeds", "5-2"], "--seeds 5-2: the range 5-2 runs backwards"),
    ],
)
def test_bad_sweep_options_are_one_line(tmp_path: Path, option: list[str], message: str) -> None:
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "harness.cli", "sweep", str(EXAMPLE), "--out", str(out), *option],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.strip().splitlines() == [f"harness: {message}"]
    assert not out.exists()
