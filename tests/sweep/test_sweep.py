"""`harness sweep` end to end: real `harness run` processes under real Dask (local cluster, and a scheduler
plus a worker started as separate processes), results.csv, plots, Ctrl-C with nothing left, resume."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from harness.pytest_plugin import SweepRecord
from harness.run.result import RunStatus
from harness.sweep.results import read_results
from tests.helpers import wait_until

pytestmark = pytest.mark.sim
WAIT_FOR_FILE = Path(__file__).resolve().parent / "scripts" / "wait_for_file.py"
ROOT = Path(__file__).resolve().parents[2]


def scenario(tmp_path: Path, speed: str = '"max"') -> Path:
    """Vehicles on the ground, each running wait_for_file.py: a run ends once its flag file exists."""
    path = tmp_path / "s.toml"
    path.write_text(
        f'seed = 0\nspeed = {speed}\nduration_s = 600\n[vehicles]\ncount = 1\nmission = "{WAIT_FOR_FILE}"\n'
        f'args = ["{tmp_path / "never"}"]\n'
    )
    return path


def pids_under(out: Path) -> list[int]:
    """Live processes of the sweep's runs: each carries HARNESS_RUN_DIR=<out>/<run> in its environment."""
    found = []
    needle = f"HARNESS_RUN_DIR={out}/".encode()
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                env = Path(f"/proc/{entry}/environ").read_bytes()
            except OSError:
                continue
            if any(var.startswith(needle) for var in env.split(b"\0")):
                found.append(int(entry))
    return found


def sweep_cmd(scenario: Path, out: Path, *args: str) -> list[str]:
    return [sys.executable, "-m", "harness.cli", "sweep", str(scenario), "--out", str(out), *args]


def _status(run_dir: Path) -> str | None:
    """The status a run's summary.json says now (None: not written yet, or caught mid-replace)."""
    try:
        return str(json.loads((run_dir / "summary.json").read_text())["status"])
    except (OSError, ValueError, KeyError):
        return None


def interrupt_when(proc: subprocess.Popen[str], out: Path, ok_runs: int, running: int, timeout_s: float = 90) -> float:
    """Wait for ``ok_runs`` finished runs and ``running`` runs under way (their missions started), then
    Ctrl-C the sweep; returns the seconds until the sweep and every process of its runs were gone."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        done = [p for p in out.glob("*/summary.json") if _status(p.parent) == RunStatus.OK]
        # summary.json is written from the start with "running" (record/status.py): a run under way says so
        going = [d for d in out.glob("*/mission-0.stdout") if _status(d.parent) in (None, RunStatus.RUNNING)]
        if len(done) >= ok_runs and len(going) >= running:
            break
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.2)
    else:
        raise AssertionError(f"expected {ok_runs} runs done and {running} going within {timeout_s} s")
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 10:
        if proc.poll() is not None and not pids_under(out):
            return time.monotonic() - t0
        time.sleep(0.05)
    return time.monotonic() - t0


def test_local_sweep_table_plugin_and_plots(tmp_path: Path, harness_sweep: Callable[..., SweepRecord]) -> None:
    flag = tmp_path / "go"
    flag.touch()
    path = scenario(tmp_path)
    sweep = harness_sweep(path, seeds="3-4", sets={"vehicles.count": [1, 2], "vehicles.args": [[str(flag)]]})
    assert sweep.ok, sweep.message
    assert len(sweep.rows) == 4
    assert sweep.column("seed") == [3, 4, 3, 4] and sweep.column("vehicles.count") == [1, 1, 2, 2]
    two = sweep.where({"vehicles.count": 2, "seed": 4})[0]
    assert two["run"] == f"seed-4_vehicles.count-2_vehicles.args-{str(flag).strip('/').replace('/', '_')}"
    assert two["v1.vehicle"] == 1 and two["v1.mission_exit_code"] == 0 and two["v1.landed"] is True
    assert sweep.where({"vehicles.count": 1})[0]["v1.vehicle"] is None  # no such vehicle: an empty cell
    for row in sweep.rows:
        assert row["status"] == "ok" and row["sim_time_s"] > 0 and row["wall_time_s"] > 0
        assert row["worker"].startswith("inproc://") and (sweep.out / row["run"] / "summary.json").is_file()
        assert json.loads((sweep.out / row["run"] / "summary.json").read_text())["seed"] == row["seed"]
    assert (sweep.out / "results.parquet").is_file() or pytest.importorskip("pyarrow") is None
    assert not pids_under(sweep.out)

    plot = subprocess.run([sys.executable, "-m", "harness.cli", "plot", str(sweep.out)], capture_output=True, text=True)
    assert plot.returncode == 0, plot.stderr
    pngs = {Path(line).name for line in plot.stdout.split() if line.endswith(".png")}
    assert {"real_time_factor_vs_vehicles_count.png", "vehicle_vs_vehicles_args.png"} <= pngs
    assert all((sweep.out / name).stat().st_size > 1000 for name in pngs)
    assert "seed-4_vehicles.count-2" in (sweep.out / "index.html").read_text()


def test_the_wind_example_reports_drift_that_grows_with_the_wind(harness_sweep: Callable[..., SweepRecord]) -> None:
    """scenarios/wind_sweep.toml as shipped (2 MAVSDK vehicles), hovering 8 s instead of 20, in 0 and 8 m/s."""
    sweep = harness_sweep(
        ROOT / "scenarios" / "wind_sweep.toml", seeds="1", sets={"wind.north_m_s": [0, 8], "vehicles.args": [["8"]]}
    )
    assert sweep.ok, sweep.message
    calm, windy = sweep.rows
    for row in sweep.rows:
        for v in (0, 1):
            assert row[f"v{v}.samples"] >= 70  # 10 Hz position telemetry over 8 s of hover
            assert row[f"v{v}.rms_alt_error_m"] < 0.3 and 9.7 < row[f"v{v}.max_altitude_m"] < 10.5
            assert row[f"v{v}.landed"] is True and row[f"v{v}.mission_exit_code"] == 0
    assert max(calm["v0.max_drift_m"], calm["v1.max_drift_m"]) < min(windy["v0.max_drift_m"], windy["v1.max_drift_m"])


def test_ctrl_c_stops_every_run_and_a_rerun_completes_only_the_missing(tmp_path: Path) -> None:
    go = tmp_path / "go"
    short = tmp_path / "short"
    short.touch()
    path = scenario(tmp_path, speed="1")  # the long runs idle at real time until `go` exists
    out = tmp_path / "sweep"
    values = f'vehicles.args=["{short}"],["{go}"]'
    cmd = sweep_cmd(path, out, "--seeds", "0-3", "--set", values, "--runs-per-worker", "2")  # 4 short, then 4 long
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    gone_s = interrupt_when(proc, out, ok_runs=4, running=2)  # 2 long runs going, 2 waiting for a thread
    stdout, stderr = proc.communicate(timeout=10)
    assert gone_s < 5.0, (gone_s, pids_under(out), stderr)
    assert proc.returncode == 130, stderr
    assert stdout.startswith("sweep of 8 runs") and "interrupted: 8 run(s) this time" in stdout
    assert "re-run the same command to finish the missing runs" in stderr
    rows = {r["run"]: r for r in read_results(out / "results.csv")}
    assert [r["status"] for r in rows.values()] == ["ok"] * 4 + ["interrupted"] * 4
    kept = {name: (out / name / "sweep-run.json").read_text() for name, r in rows.items() if r["status"] == "ok"}
    stopped = [name for name, r in rows.items() if r["status"] == "interrupted"]
    started = [name for name in stopped if rows[name]["message"] != "stopped before it started"]
    assert len(started) == 2, rows  # the queued ones were not started once the sweep was stopping
    for name in started:  # harness run was stopped by SIGTERM, not killed: it wrote its summary
        assert json.loads((out / name / "summary.json").read_text())["status"] == "interrupted"

    go.touch()
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr
    assert "4 run(s) this time, 4 kept from before" in again.stdout
    rows = {r["run"]: r for r in read_results(out / "results.csv")}
    assert len(rows) == 8 and all(r["status"] == "ok" for r in rows.values())
    assert {name: (out / name / "sweep-run.json").read_text() for name in kept} == kept  # not run again
    assert all(rows[name]["v0.waited_s"] is not None for name in stopped)
    assert not pids_under(out)


def test_failures_are_rows_and_the_sweep_goes_on(tmp_path: Path) -> None:
    short = tmp_path / "short"
    short.touch()
    path = scenario(tmp_path, speed="1")
    out = tmp_path / "sweep"
    values = f'vehicles.args=["{short}"],["fail"],["{tmp_path / "never"}"]'
    # one at a time, so that under load an ok run (~1-2 s) never comes near the timeout
    cmd = sweep_cmd(path, out, "--set", values, "--runs-per-worker", "1")
    first = subprocess.run([*cmd, "--run-timeout", "10"], capture_output=True, text=True, timeout=120)
    assert first.returncode == 1, first.stderr
    rows = read_results(out / "results.csv")
    assert [r["status"] for r in rows] == ["ok", "failed", "timeout"]
    assert "the mission of vehicle 0 exited with 3" in rows[1]["message"] and rows[1]["v0.mission_exit_code"] == 3
    assert rows[2]["message"] == "stopped after 10 s of wall time (--run-timeout)"
    assert not pids_under(out)
    # a re-run keeps ok runs (and failed ones, unless --retry-failed) and tries timed-out ones again
    retry = subprocess.run([*cmd, "--retry-failed", "--run-timeout", "2"], capture_output=True, text=True, timeout=120)
    assert "2 run(s) this time, 1 kept from before" in retry.stdout, retry.stderr


def test_a_killed_sweep_leaves_no_process(tmp_path: Path) -> None:
    """kill -9 of `harness sweep` (local cluster): the kernel kills each run (PR_SET_PDEATHSIG on the worker
    thread that started it) and each run's children in turn."""
    path = scenario(tmp_path, speed="1")
    out = tmp_path / "sweep"
    proc = subprocess.Popen(sweep_cmd(path, out, "--seeds", "0-1"), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    while len(pids_under(out)) < 4 and time.monotonic() < deadline:  # 2 x (harness run + its mission)
        time.sleep(0.2)
    assert len(pids_under(out)) >= 4, proc.stderr.read() if proc.poll() is not None and proc.stderr else ""
    proc.kill()
    proc.wait()
    t0 = time.monotonic()
    while pids_under(out) and time.monotonic() - t0 < 10:
        time.sleep(0.05)
    assert not pids_under(out), f"still running {time.monotonic() - t0:.1f} s after kill -9: {pids_under(out)}"
    assert time.monotonic() - t0 < 5.0


@dataclass
class DaskCluster:
    address: str
    scheduler: subprocess.Popen[bytes]
    worker: subprocess.Popen[bytes]


@pytest.fixture
def dask_cluster(tmp_path: Path) -> Iterator[DaskCluster]:
    """`dask scheduler` and one `dask worker` (2 threads) as separate processes on loopback."""
    sched_file = tmp_path / "scheduler.json"
    procs: list[subprocess.Popen[bytes]] = []

    def start(*args: str) -> subprocess.Popen[bytes]:
        log = (tmp_path / f"dask-{len(procs)}.log").open("w")
        procs.append(subprocess.Popen(args, stdout=log, stderr=log, start_new_session=True))
        return procs[-1]

    try:
        scheduler = start(
            sys.executable,
            "-m",
            "distributed.cli.dask_scheduler",
            "--host",
            "127.0.0.1",
            "--port",
            "0",
            "--no-dashboard",
            "--scheduler-file",
            str(sched_file),
        )
        deadline = time.monotonic() + 60
        address = ""
        while not address and time.monotonic() < deadline:
            try:
                address = json.loads(sched_file.read_text())["address"]
            except (OSError, ValueError, KeyError):
                time.sleep(0.1)
        worker = start(
            sys.executable,
            "-m",
            "distributed.cli.dask_worker",
            address,
            "--nthreads",
            "2",
            "--no-dashboard",
            "--host",
            "127.0.0.1",
            "--name",
            "test-worker",
        )
        yield DaskCluster(address, scheduler, worker)
    finally:
        for p in reversed(procs):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()


def test_sweep_on_a_scheduler_and_a_worker_process(tmp_path: Path, dask_cluster: DaskCluster) -> None:
    go = tmp_path / "go"
    short = tmp_path / "short"
    short.touch()
    path = scenario(tmp_path, speed="1")
    out = tmp_path / "sweep"
    cmd = sweep_cmd(path, out, "--set", f'vehicles.args=["{short}"],["{go}"]', "--scheduler", dask_cluster.address)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    gone_s = interrupt_when(proc, out, ok_runs=1, running=1, timeout_s=120)  # the worker may still be registering
    _, stderr = proc.communicate(timeout=10)
    assert gone_s < 5.0 and proc.returncode == 130, (gone_s, pids_under(out), stderr)

    go.touch()
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr
    assert "1 run(s) this time, 1 kept from before" in again.stdout
    rows = read_results(out / "results.csv")
    assert [r["status"] for r in rows] == ["ok", "ok"]
    assert all(r["worker"].startswith("tcp://127.0.0.1:") for r in rows)  # ran on the worker process
    assert rows[1]["v0.vehicle"] == 0 and rows[1]["v0.waited_s"] is not None
    assert not pids_under(out)


def test_a_lost_scheduler_ends_the_sweep_in_one_line_and_stops_the_runs(
    tmp_path: Path, dask_cluster: DaskCluster
) -> None:
    path = scenario(tmp_path, speed="1")
    out = tmp_path / "sweep"
    proc = subprocess.Popen(
        sweep_cmd(path, out, "--seeds", "0-1", "--scheduler", dask_cluster.address),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 120
    while len(list(out.glob("*/mission-0.stdout"))) < 2 and time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.2)
    dask_cluster.scheduler.kill()
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert stderr.strip().splitlines()[-1] == (
        "harness: lost the connection to the Dask scheduler; 2 run(s) did not finish (their workers stopped "
        "them): re-run the same command to finish them"
    )
    wait_until(lambda: not pids_under(out), 10.0, "every process of the runs gone", poll_s=0.1)
