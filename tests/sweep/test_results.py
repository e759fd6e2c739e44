"""results.csv rows from run directories: summary fields, per-vehicle fields, mission metrics; resume decisions."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from harness import metrics
from harness.sweep.results import read_results, row_from_run_dir, write_results
from harness.sweep.task import MARKER, finished_row


def fake_run(run_dir: Path, status: str = "ok", vehicles: int = 2, metrics_of: dict[int, object] | None = None) -> Path:
    run_dir.mkdir(parents=True)
    summary = {
        "status": status,
        "message": "" if status == "ok" else "the mission of vehicle 1 exited with 1 (exit)",
        "sim_time_s": 42.5,
        "wall_time_s": 2.5,
        "real_time_factor": 17.0,
        "vehicles": [
            {
                "id": i,
                "mission": "m.py",
                "mission_exit_code": 0,
                "max_altitude_m": 10.0 + i,
                "final_position_ned_m": [1.0 * i, 2.0, -0.1],
                "landed": True,
                "armed": False,
                "crashed": False,
            }
            for i in range(vehicles)
        ],
        "faults": [{"peer": "x"}] if status != "ok" else [],
    }
    (run_dir / "summary.json").write_text(json.dumps(summary))
    for i, data in (metrics_of or {}).items():
        (run_dir / f"metrics-{i}.json").write_text(json.dumps(data))
    return run_dir


def test_row_has_params_summary_vehicles_and_metrics(tmp_path: Path) -> None:
    run = fake_run(tmp_path / "seed-3", metrics_of={0: {"max_drift_m": 0.25, "path": [1, 2]}, 1: {"max_drift_m": 0.5}})
    row = row_from_run_dir(run, {"wind.north_m_s": 8}, 3)
    assert row["run"] == "seed-3" and row["seed"] == 3 and row["wind.north_m_s"] == 8
    assert (row["status"], row["sim_time_s"], row["wall_time_s"], row["real_time_factor"]) == ("ok", 42.5, 2.5, 17.0)
    assert row["v1.max_altitude_m"] == 11.0 and row["v1.final_north_m"] == 1.0 and row["v1.final_down_m"] == -0.1
    assert row["v0.landed"] is True and row["v0.mission_exit_code"] == 0 and row["faults"] == 0
    assert row["v0.max_drift_m"] == 0.25 and row["v1.max_drift_m"] == 0.5 and row["v0.path"] == "[1, 2]"


def test_a_broken_metrics_file_is_left_out(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    run = fake_run(tmp_path / "r", vehicles=1)
    (run / "metrics-0.json").write_text("{not json")
    row = row_from_run_dir(run, {}, 0)
    assert row["status"] == "ok" and row["v0.max_altitude_m"] == 10.0
    assert {k for k in row if k.startswith("v0.")} == {
        f"v0.{k}" for k in ("mission_exit_code", "max_altitude_m", "final_north_m", "final_east_m", "final_down_m")
    } | {"v0.landed", "v0.armed", "v0.crashed"}
    assert "not readable as JSON" in caplog.text


def test_csv_and_parquet_have_every_column_in_order(tmp_path: Path) -> None:
    rows = [
        row_from_run_dir(fake_run(tmp_path / "a", vehicles=1), {"vehicles.count": 1}, 0),
        row_from_run_dir(fake_run(tmp_path / "b", "failed", 2, {1: {"score": 3}}), {"vehicles.count": 2}, 1),
    ]
    written = write_results(tmp_path, rows, ["vehicles.count"])
    back = read_results(tmp_path / "results.csv")
    header = list(back[0])
    assert header[:10] == [
        "run",
        "seed",
        "vehicles.count",
        "status",
        "message",
        "sim_time_s",
        "wall_time_s",
        "real_time_factor",
        "faults",
        "worker",
    ]
    assert header.index("v0.max_altitude_m") < header.index("v1.mission_exit_code") < header.index("v1.score")
    assert back[0]["v1.max_altitude_m"] is None and back[1]["v1.max_altitude_m"] == 11.0  # empty cell, value
    assert back[1]["status"] == "failed" and back[1]["faults"] == 1 and back[1]["v1.score"] == 3
    assert back[0]["v0.landed"] is True
    pq = pytest.importorskip("pyarrow.parquet")
    assert tmp_path / "results.parquet" in written
    table = pq.read_table(tmp_path / "results.parquet").to_pylist()
    assert [r["run"] for r in table] == ["a", "b"] and table[1]["v1.score"] == 3 and table[0]["v1.score"] is None


def test_resume_keeps_ok_and_failed_runs_with_the_same_parameters(tmp_path: Path) -> None:
    def marked(name: str, status: str, params: dict[str, object], seed: int) -> Path:
        run = fake_run(tmp_path / name, status)
        (run / MARKER).write_text(json.dumps({"params": params, "seed": seed, "worker": "w"}))
        return run

    assert finished_row(marked("ok", "ok", {"a": 1}, 0), {"a": 1}, 0) is not None
    assert finished_row(marked("failed", "failed", {"a": 1}, 0), {"a": 1}, 0) is not None
    assert finished_row(marked("int", "interrupted", {"a": 1}, 0), {"a": 1}, 0) is None
    assert finished_row(marked("other", "ok", {"a": 2}, 0), {"a": 1}, 0) is None  # other parameters: run again
    assert finished_row(fake_run(tmp_path / "nomarker"), {}, 0) is None
    assert finished_row(tmp_path / "missing", {}, 0) is None


def test_metrics_report_merges_and_is_quiet_outside_a_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("HARNESS_RUN_DIR", raising=False)
    assert metrics.report(x=1) is None
    monkeypatch.setenv("HARNESS_RUN_DIR", str(tmp_path))
    monkeypatch.setenv("HARNESS_VEHICLE", "2")
    metrics.report(max_drift_m=0.5, ok=True)
    path = metrics.report(max_drift_m=0.75, nan=float("nan"))
    assert path == tmp_path / "metrics-2.json"
    assert json.loads(path.read_text()) == {"max_drift_m": 0.75, "ok": True, "nan": None}
    with pytest.raises(TypeError, match="metric bad"):
        metrics.report(bad=[1, 2])  # type: ignore[arg-type]


def test_progress_bar_line() -> None:
    from harness.sweep.runner import SweepProgress

    assert SweepProgress(8, 2, 0, 1, 10.4, 30.2).bar(8) == "[##......] 2/8 runs  1 not ok  10 s  ~30 s left"
    assert SweepProgress(8, 8, 4, 0, 61.0, 0.0).bar(8) == "[########] 8/8 runs (4 kept)  0 not ok  61 s"


def test_runs_per_worker_caps_the_runs_at_once_in_a_worker(monkeypatch: pytest.MonkeyPatch) -> None:
    """--runs-per-worker with a scheduler: a per-process semaphore around each run (the run itself stubbed)."""
    import threading
    import time

    from harness.core.clock import WALL, Clock
    from harness.sweep import task

    lock = threading.Lock()
    now = [0]
    peak = [0]

    def fake_run(job: task.RunJob, clock: Clock) -> dict[str, object]:
        assert clock is WALL
        with lock:
            now[0] += 1
            peak[0] = max(peak[0], now[0])
        time.sleep(0.2)
        with lock:
            now[0] -= 1
        return {"run": job.name, "status": "ok"}

    monkeypatch.setattr(task, "_run", fake_run)
    jobs = [task.RunJob(f"r{i}", "s.toml", f"/nonexistent/r{i}", i, (), slots=2) for i in range(6)]
    threads = [threading.Thread(target=task.run_job, args=(j,)) for j in jobs]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    assert peak[0] == 2 and now[0] == 0
