"""The Dask task of a sweep: one ``harness run`` as a subprocess of the worker, stoppable from the client.

The run gets its own process group and ``PR_SET_PDEATHSIG`` (SIGKILL when the worker thread that started it
dies, even by ``kill -9``); ``harness run`` does the same for its own children, so a killed worker leaves
nothing behind. While the run goes on the task checks, every ``POLL_S``, the sweep's stop event (Ctrl-C on
the client), whether Dask cancelled the task, and the wall-clock timeout; on any of them the run's group
gets SIGTERM (``harness run`` stops its children and writes its summary), then SIGKILL after ``grace_s``.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from harness.core import lifeline
from harness.core.clock import NS_PER_S, WALL, Clock
from harness.run.result import RunStatus
from harness.sweep.results import FINISHED, row_from_run_dir

POLL_S = 0.25
MARKER = "sweep-run.json"


@dataclass(frozen=True)
class RunJob:
    """Everything a worker needs for one run (plain data: it travels to the worker pickled)."""

    name: str
    scenario: str
    run_dir: str
    seed: int
    sets: tuple[tuple[str, str], ...]
    params: dict[str, Any] = field(default_factory=dict)
    timeout_s: float | None = None
    stop_event: str | None = None
    """Name of the sweep's ``distributed.Event``; set = stop now."""
    slots: int | None = None
    """At most this many runs at once in one worker process (``--runs-per-worker``); None: the worker's threads."""
    grace_s: float = 3.0

    def argv(self) -> list[str]:
        cmd = [sys.executable, "-m", "harness.cli", "run", self.scenario, "--out", self.run_dir]
        cmd += ["--seed", str(self.seed), "--no-progress"]
        for path, text in self.sets:
            cmd += ["--set", f"{path}={text}"]
        return cmd


_slots_lock = threading.Lock()
_slots: dict[int, threading.BoundedSemaphore] = {}


def _worker_slots(n: int) -> threading.BoundedSemaphore:
    with _slots_lock:
        return _slots.setdefault(n, threading.BoundedSemaphore(n))


def run_job(job: RunJob, clock: Clock = WALL) -> dict[str, Any]:
    """The Dask task: run ``job`` (waiting for a slot first) and return its results.csv row."""
    if job.slots is None:
        return _run(job, clock)
    slots = _worker_slots(job.slots)
    watch = _StopWatch(job.stop_event, clock)
    while not slots.acquire(timeout=POLL_S):
        if watch.why() is not None:
            return _row_without_summary(job, RunStatus.INTERRUPTED, "stopped before it started")
    try:
        return _run(job, clock)
    finally:
        slots.release()


def finished_row(run_dir: Path, params: Mapping[str, Any], seed: int) -> dict[str, Any] | None:
    """The row of a run a previous sweep finished with the same parameters, else None (run it again)."""
    try:
        marker = json.loads((run_dir / MARKER).read_text())
        row = row_from_run_dir(run_dir, params, seed)
    except (OSError, ValueError):
        return None
    if marker.get("params") != json.loads(json.dumps(dict(params), default=str)) or marker.get("seed") != seed:
        return None
    if row.get("status") not in FINISHED:
        return None
    row["worker"] = marker.get("worker")
    return row


def _run(job: RunJob, clock: Clock) -> dict[str, Any]:
    watch = _StopWatch(job.stop_event, clock)
    if watch.why() is not None:  # queued while the sweep was being stopped: do not start it at all
        return _row_without_summary(job, RunStatus.INTERRUPTED, "stopped before it started")
    run_dir = Path(job.run_dir)
    if run_dir.exists():
        if not (run_dir / MARKER).is_file() and any(run_dir.iterdir()):
            return _row_without_summary(
                job, RunStatus.LOST, f"{run_dir} exists and is not a sweep run: move it away and re-run"
            )
        shutil.rmtree(run_dir)  # a previous attempt's files (an old metrics file would become a wrong column)
    run_dir.mkdir(parents=True)
    where = _worker_name()
    marker: dict[str, Any] = {
        "name": job.name,
        "seed": job.seed,
        "params": job.params,
        "command": job.argv(),
        "worker": where,
        "started_unix_s": clock.unix_ns() / NS_PER_S,
    }
    (run_dir / MARKER).write_text(json.dumps(marker, indent=2))
    env = dict(os.environ, HARNESS_RUN_DIR=str(run_dir))
    with (run_dir / "harness-run.stdout").open("wb") as out, (run_dir / "harness-run.stderr").open("wb") as err:
        proc = subprocess.Popen(
            job.argv(),
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=err,
            env=lifeline.tied_env(env),  # harness run ties itself to this thread first thing (PR_SET_PDEATHSIG)
            process_group=0,  # its own group: stopped as a group; Ctrl-C at a terminal does not reach it
        )
    status: RunStatus | None = None
    reason = ""
    started = clock.now_ns()
    try:
        while True:
            try:
                proc.wait(POLL_S)
                break
            except subprocess.TimeoutExpired:
                pass
            if job.timeout_s is not None and (clock.now_ns() - started) / NS_PER_S > job.timeout_s:
                status, reason = RunStatus.TIMEOUT, f"stopped after {job.timeout_s:g} s of wall time (--run-timeout)"
            else:
                why = watch.why()
                if why is not None:
                    status, reason = RunStatus.INTERRUPTED, why
            if status is not None:
                _stop(proc, job.grace_s)
                break
    finally:
        if proc.poll() is None:  # an exception in this thread: the run must not outlive it
            _stop(proc, 0.0)
    marker["returncode"] = proc.returncode
    marker["ended_unix_s"] = clock.unix_ns() / NS_PER_S
    (run_dir / MARKER).write_text(json.dumps(marker, indent=2))
    try:
        row = row_from_run_dir(run_dir, job.params, job.seed)
    except (OSError, ValueError):
        tail = _last_line(run_dir / "harness-run.stderr")
        return _row_without_summary(
            job,
            status or RunStatus.LOST,
            reason or f"harness run exited with {proc.returncode} and wrote no summary: {tail}",
        )
    if status is not None and row.get("status") not in FINISHED:  # a run that ended just before: its own result
        row["status"], row["message"] = str(status), reason
    row["worker"] = where
    return row


def _row_without_summary(job: RunJob, status: RunStatus, message: str) -> dict[str, Any]:
    return {
        "run": job.name,
        "seed": job.seed,
        **job.params,
        "status": str(status),
        "message": message,
        "worker": _worker_name(),
    }


def _stop(proc: subprocess.Popen[bytes], grace_s: float) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(grace_s)
    except subprocess.TimeoutExpired:
        pass
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


class _StopWatch:
    """Why the run must stop now: the sweep's stop event is set (Ctrl-C on the client), Dask cancelled the
    task (the client cancelled it or went away), or the scheduler cannot be asked. Outside a Dask worker (a
    direct call) there is nothing to watch. The event, a call to the scheduler, is asked every
    ``EVENT_EVERY_S``; the task's state, local to the worker, at every call."""

    EVENT_EVERY_S = 0.5

    def __init__(self, stop_event: str | None, clock: Clock) -> None:
        self.clock = clock
        self.worker: Any = None
        self.event: Any = None
        self.next_ask = 0.0
        try:
            from distributed import Event, get_worker

            self.worker = get_worker()
        except (ImportError, ValueError):
            return
        self.key = self.worker.get_current_task()
        if stop_event is not None:
            self.event = Event(stop_event)

    def why(self) -> str | None:
        if self.worker is None:
            return None
        ts = self.worker.state.tasks.get(self.key) if self.key is not None else None
        if ts is None or ts.state in ("cancelled", "released", "forgotten"):
            return "the sweep cancelled the run"
        if self.event is None or self.clock.now_ns() / NS_PER_S < self.next_ask:
            return None
        self.next_ask = self.clock.now_ns() / NS_PER_S + self.EVENT_EVERY_S
        try:
            if self.event.is_set():
                return "the sweep was stopped (Ctrl-C)"
        except Exception as exc:  # the scheduler is unreachable: nobody waits for this run any more
            return f"lost the scheduler ({exc.__class__.__name__})"
        return None


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):
        return socket.gethostname()


def _last_line(path: Path) -> str:
    try:
        lines = [line for line in path.read_text(errors="replace").splitlines() if line.strip()]
    except OSError:
        return "(no stderr)"
    return lines[-1][-300:] if lines else "(stderr empty)"
