"""Every bad input is refused before anything starts: one line naming the field, exit code 2, within seconds,
nothing left running (issue 17, item 6)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from harness.core.errors import ScenarioError
from harness.scenario import limits
from harness.scenario.limits import check_plan, memory_estimate_mb
from harness.scenario.plan import LaunchPlan, MissionPlan

ROOT = Path(__file__).resolve().parents[2]
NOT_ROOT = os.geteuid() != 0
LOW = limits.lowest_port()


def harness_fails(tmp_path: Path, *args: str) -> str:
    """Run ``harness``; assert exit code 2 within seconds, one line on stderr, nothing started. The line."""
    out = tmp_path / "out"
    start = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "harness.cli", *args], capture_output=True, text=True, timeout=60, cwd=tmp_path
    )
    elapsed = time.monotonic() - start
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert elapsed < 8.0, f"took {elapsed:.1f} s to refuse"
    assert not (out / "summary.json").exists(), "a run started"
    assert not _processes_of(out)
    return lines[0]


def _processes_of(run_dir: Path) -> list[int]:
    needle = f"HARNESS_RUN_DIR={run_dir}".encode()
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                if needle in Path(f"/proc/{entry}/environ").read_bytes().split(b"\0"):
                    found.append(int(entry))
            except OSError:
                continue
    return found


SCENARIOS = [
    (
        "[vehicles]\ncount = 2\nparams = { MPC_XY_VEL_MAX = 1e30 }",
        "vehicles.params: vehicle 0: parameter override MPC_XY_VEL_MAX=1e+30: MPC_XY_VEL_MAX=1e+30 outside [0, 20]",
    ),
    (
        "[[vehicles]]\n[[vehicles]]\nparams = { NOPE_X = 1 }",
        "vehicles.params: vehicle 1: parameter override NOPE_X=1.0: unknown parameter 'NOPE_X'",
    ),
    (
        "[vehicles]\ncount = 2\nspacing_m = 1e300",
        "vehicles: vehicle 1 would start at (0.0, 1e+300, 0.0) m, more than 100 km from the origin or 1 km above "
        "or below it",
    ),
    (
        "vehicles = 100000",
        "vehicles: must be 1-244 on one machine (vehicle i is MAVLink system id i + 1; 245 and 255 are ground "
        "stations; more on a Dask cluster: --cluster local:K or --scheduler ADDRESS), got 100000",
    ),
    (
        "vehicles = 1\n[mavlink]\napi_port_base = 70000",
        f"mavlink.api_port_base: must be a port number {LOW}-65535, got 70000",
    ),
    (
        "vehicles = 3\n[mavlink]\napi_port_base = 65534",
        "mavlink.api_port_base: 65534 + 2 more ports goes past 65535 (to 65536) for 3 vehicles",
    ),
    (
        "vehicles = 1\n[mavlink]\ngcs_port = 99999",
        f"mavlink.gcs_port: must be a port number {LOW}-65535 (or 0: off), got 99999",
    ),
    (
        "vehicles = 1\n[rates]\nphysics_hz = 1e-300\ntick_hz = 1e-300",
        "rates.physics_hz: must be >= 10 and <= 100000, got 1e-300",
    ),
    (
        "vehicles = 1\n[rates]\ntick_hz = 1e-300",
        "rates.tick_hz: must be >= 1 and <= 1000, got 1e-300",
    ),
    ("vehicles = 1\n[rates]\nphysics_hz = 1000\ntick_hz = 0.5", "rates.tick_hz: must be >= 1 and <= 1000, got 0.5"),
    (
        "vehicles = 1\n[rates]\nphase_every = 100000",
        "rates.phase_every: 100000 ticks at 250 Hz is a phase period over 10 s",
    ),
    (
        "vehicles = 1\n[channel]\nstall_timeout_s = 1e300",
        "channel.stall_timeout_s: must be > 0 and <= 86400, got 1e+300",
    ),
    ("vehicles = 1\nduration_s = 1e300", "duration_s: must be >= 0.004 and <= 1e+09, got 1e+300"),
    ("vehicles = 1\nduration_s = 0.001", "duration_s: must be >= 0.004 and <= 1e+09, got 0.001"),
    ("vehicles = 1\nspeed = 1e300", "speed: must be > 0 and <= 1e+06, got 1e+300"),
    ("vehicles = 1\n[world]\nlat_deg = 95", "world.lat_deg: must be >= -90 and <= 90, got 95.0"),
    ("vehicles = 1\n[wind]\nnorth_m_s = 1e9", "wind.north_m_s: must be >= -100 and <= 100, got 1000000000.0"),
    (
        'vehicles = 1\n[network]\nmodel = "builtin"\nparams = { bogus = 1 }',
        "network.params.bogus: unknown parameter (valid: bit_rate_bps, capture_db, carrier_sense_dbm, frequency_hz, "
        "header_bytes, max_range_m, noise_floor_dbm, path_loss_exponent, preamble_s, queue_limit, shadowing_sigma_db, "
        "slot_s, tx_power_dbm)",
    ),
    (
        'vehicles = 1\n[network]\nmodel = "builtin"\nparams = { tx_power_dbm = nan }',
        "network.params.tx_power_dbm: expected a finite number, got nan",
    ),
    (
        'vehicles = 1\n[network]\nmodel = "ns3"\nparams = { bogus = 1 }',
        "network.params.bogus: unknown ns-3 parameter (valid: max_vehicles, path_loss_exponent, standard, tx_power_dbm)",
    ),
]


@pytest.mark.parametrize(
    ("text", "expected"), SCENARIOS, ids=[e.split(":")[0] + str(i) for i, (_, e) in enumerate(SCENARIOS)]
)
def test_bad_scenario_value_is_one_line_naming_the_field(tmp_path: Path, text: str, expected: str) -> None:
    (tmp_path / "s.toml").write_text('out = "out"\n' + text + "\n")
    assert harness_fails(tmp_path, "run", "s.toml") == f"harness: s.toml: {expected}"


def _arg_error(option: str, why: str, value: str) -> str:
    return f"harness run: error: argument {option}: {why}, got {value!r} (see harness run --help)"


DURATION = "must be a finite number > 0 and <= 1e+09"
COMMAND_LINES = [
    (["--duration", "nan"], _arg_error("--duration", DURATION, "nan")),
    (["--duration", "inf"], _arg_error("--duration", DURATION, "inf")),
    (["--duration", "-1"], _arg_error("--duration", DURATION, "-1")),
    (["--duration", "0"], _arg_error("--duration", DURATION, "0")),
    (
        ["--vehicles", "100000"],
        "harness: --vehicles: must be 1-244 on one machine (vehicle i is MAVLink system id i + 1; 245 and 255 are "
        "ground stations; more on a Dask cluster: --cluster local:K or --scheduler ADDRESS), got 100000",
    ),
    (["--vehicles", "0"], _arg_error("--vehicles", "must be an integer 1-1000000", "0")),
    (["--speed", "inf"], _arg_error("--speed", "must be 'max' or a finite number > 0", "inf")),
    (["--seed", "-1"], _arg_error("--seed", f"must be an integer 0-{2**63 - 1}", "-1")),
    (["--pause-for", "nan"], _arg_error("--pause-for", "must be a finite number > 0 and <= 86400", "nan")),
    (["--tcp-port-base", "70000"], _arg_error("--tcp-port-base", f"must be an integer {LOW}-65535", "70000")),
    (
        ["--vehicles", "3", "--tcp-port-base", "65534"],
        "harness: --tcp-port-base: 65534 + 2 more ports goes past 65535 (to 65536) for 3 vehicles",
    ),
]


@pytest.mark.parametrize(("args", "expected"), COMMAND_LINES, ids=[" ".join(a) for a, _ in COMMAND_LINES])
def test_bad_command_line_value_is_one_line_naming_the_option(tmp_path: Path, args: list[str], expected: str) -> None:
    assert harness_fails(tmp_path, "run", *args, "--out", "out") == expected


@pytest.mark.skipif(not NOT_ROOT, reason="root may bind ports below 1024")
def test_privileged_port_is_refused_unless_root(tmp_path: Path) -> None:
    (tmp_path / "s.toml").write_text('vehicles = 1\nout = "out"\n[mavlink]\napi_port_base = 80\n')
    line = harness_fails(tmp_path, "run", "s.toml")
    assert (
        line
        == "harness: s.toml: mavlink.api_port_base: must be a port number 1024-65535, got 80 (ports below 1024 need root)"
    )


def test_run_that_does_not_fit_in_memory_is_refused(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    script = tmp_path / "m.py"
    script.write_text("")
    plan = LaunchPlan(vehicles=100, out=tmp_path, missions=(MissionPlan(script),) * 100)
    need = memory_estimate_mb(100, 100, False)
    assert need == 140 + 2 * 100 + 80 * 100
    monkeypatch.setattr(limits, "available_memory_mb", lambda: need - 1)
    with pytest.raises(
        ScenarioError,
        match=rf"^vehicles: 100 vehicles with 100 missions need about {need} MB of memory, "
        rf"the machine has {need - 1} MB available$",
    ):
        check_plan(plan)
    monkeypatch.setattr(limits, "available_memory_mb", lambda: need)
    check_plan(plan)  # fits exactly


def test_launcher_checks_a_plan_built_in_python(tmp_path: Path) -> None:
    from harness.run.launcher import Launcher

    with pytest.raises(ScenarioError, match=r"^stall_timeout_s: must be a finite number, got inf$"):
        Launcher(LaunchPlan(vehicles=1, out=tmp_path / "x", stall_timeout_s=float("inf")))
    assert not (tmp_path / "x").exists()


def test_ports_below_1024_only_as_root(tmp_path: Path) -> None:
    plan = LaunchPlan(vehicles=1, out=tmp_path, api_port_base=80)
    if NOT_ROOT:
        with pytest.raises(ScenarioError, match=r"ports below 1024 need root"):
            check_plan(plan)
    else:
        check_plan(plan)
    with pytest.raises(ScenarioError, match=r"^api_port_base: must be a port number \d+-65535, got 0$"):
        check_plan(LaunchPlan(vehicles=1, out=tmp_path, api_port_base=0))


@pytest.mark.parametrize(
    ("text", "says", "cut"),
    [
        ("x = " + "[" * 1000 + "]" * 1000 + "\n", "nested deeper than 16 levels", False),
        ("x = " + "[" * 20 + "]" * 20 + "\n", "nested deeper than 16 levels", False),
        ("vehicles = 1\n" + "# padding\n" * 200_000, "bytes, more than the 1,048,576 it may have", False),
        ("vehicles = 1\n" + "k" * 500_000 + " = 1\n", "unknown key", True),
        ('vehicles = 1\n[rates]\ntick_hz = "' + "9" * 500_000 + '"\n', "expected a number, got str", True),
    ],
    ids=["nested-1000", "nested-20", "two-megabytes", "long-key", "long-value"],
)
def test_scenario_files_that_are_too_deep_too_big_or_echo_long_values_are_one_short_line(
    tmp_path: Path, text: str, says: str, cut: bool
) -> None:
    """Issue 36, item 7: a TOML nested 1,000 deep ended in a RecursionError traceback (exit 1); a 10 MB unknown key
    was one line of 10,000,160 bytes. Now: one short line, exit 2; an echoed value is cut with "…"."""
    path = tmp_path / "s.toml"
    path.write_text(text)
    line = harness_fails(tmp_path, "run", str(path))
    assert says in line and len(line) < 400, line[:500]
    assert ("…" in line) == cut  # the echoed key or value is cut
