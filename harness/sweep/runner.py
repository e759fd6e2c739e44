"""Runs a sweep on Dask distributed: an embedded local cluster, or a scheduler's address for a cluster.

Runs that a previous sweep into the same directory finished (status ok or failed, same parameters) are
kept; the others are submitted, one Dask task each (``harness.sweep.task.run_job``). ``results.csv`` is
rewritten as each run ends, so it is complete up to that point even after Ctrl-C. On KeyboardInterrupt
(Ctrl-C, or SIGTERM via the CLI) the sweep sets its stop event: every worker SIGTERMs its runs, which
write their summaries as interrupted; the client waits for that (a few seconds at most), then cancels
what is left and closes the cluster.
"""

from __future__ import annotations

import json
import logging
import os
import re
import threading
import uuid
from collections.abc import Callable
from concurrent.futures import CancelledError
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from harness.core.clock import NS_PER_S, WALL, Clock
from harness.core.errors import ScenarioError, SimulationError
from harness.run.result import RunStatus
from harness.sweep.results import write_results
from harness.sweep.spec import SweepSpec
from harness.sweep.task import RunJob, finished_row, run_job

log = logging.getLogger(__name__)

STOP_WAIT_S = 4.0
"""After Ctrl-C, how long the client waits for the workers to stop their runs (they need ~2 s)."""
CLOSE_S = 4.0
"""How long closing the client, and then the local cluster, may take at the end of a sweep."""
CLOSE_STOPPING_S = 0.5
"""The same after Ctrl-C, when every run has stopped: a graceful close of Dask's scheduler took 5 s and more
on a loaded machine, and nothing is left for it to do (the in-process cluster ends with this process)."""
HEALTH_EVERY_S = 5.0
SCHEDULER_LOST_S = 60.0
_ADDRESS = re.compile(r"^([a-z]+://)?[^\s:/]+:\d+$")
"""A sweep whose client has been cut off from the scheduler this long fails with a clear message."""


@dataclass(frozen=True)
class SweepOptions:
    out: Path
    scheduler: str | None = None
    """``tcp://HOST:8786``; None: a local cluster inside this process."""
    runs_per_worker: int | None = None
    """Runs at once per worker. Local cluster: its thread count (default: the CPU count). With a scheduler:
    a limit inside each worker process (default: the worker's ``--nthreads``)."""
    run_timeout_s: float | None = None
    retry_failed: bool = False

    def __post_init__(self) -> None:
        if self.runs_per_worker is not None and self.runs_per_worker < 1:
            raise ScenarioError(f"--runs-per-worker must be >= 1, got {self.runs_per_worker}")
        if self.run_timeout_s is not None and not self.run_timeout_s > 0:
            raise ScenarioError(f"--run-timeout must be > 0 seconds, got {self.run_timeout_s}")
        if self.scheduler is not None and not _ADDRESS.match(self.scheduler):
            raise ScenarioError(f"--scheduler {self.scheduler}: expected a Dask scheduler address like tcp://HOST:8786")


@dataclass
class SweepProgress:
    total: int
    done: int
    kept: int
    """Finished by an earlier sweep into the same directory."""
    failed: int
    elapsed_s: float
    eta_s: float | None
    last: str = ""
    """What just happened (``seed-3_wind.north_m_s-8: ok``, ``waiting for a Dask worker ...``)."""

    def bar(self, width: int = 30) -> str:
        """``[#######.......] 2/8 runs  0 not ok  10 s  ~30 s left``."""
        filled = width * self.done // max(1, self.total)
        eta = f"  ~{self.eta_s:.0f} s left" if self.eta_s is not None and self.done < self.total else ""
        kept = f" ({self.kept} kept)" if self.kept else ""
        return (
            f"[{'#' * filled}{'.' * (width - filled)}] {self.done}/{self.total} runs{kept}  "
            f"{self.failed} not ok  {self.elapsed_s:.0f} s{eta}"
        )


def quiet_dask(quiet: bool) -> None:
    """Dask's own INFO logging off unless asked for (``-v``); its loggers are set up when it is imported."""
    import distributed  # noqa: F401

    if quiet:  # the sweep reports what matters (a lost scheduler, failed runs) in its own words
        names = [n for n in logging.root.manager.loggerDict if n == "distributed" or n.startswith("distributed.")]
        for name in ["distributed", *names]:  # Dask's config gives some children their own level
            logging.getLogger(name).setLevel(logging.CRITICAL)


@dataclass
class SweepOutcome:
    rows: list[dict[str, Any]]
    ran: int
    kept: int
    interrupted: bool
    wall_time_s: float
    files: list[Path]

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [r for r in self.rows if r.get("status") != RunStatus.OK]

    @property
    def exit_code(self) -> int:
        return 130 if self.interrupted else (1 if self.failed else 0)


def run_sweep(
    spec: SweepSpec,
    opts: SweepOptions,
    progress: Callable[[SweepProgress], None] | None = None,
    clock: Clock = WALL,
) -> SweepOutcome:
    def now_s() -> float:
        return clock.now_ns() / NS_PER_S

    out = opts.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    (out / "sweep.json").write_text(json.dumps(spec.describe(), indent=2, default=str))
    params = [p.path for p in spec.params]
    rows: dict[str, dict[str, Any]] = {}
    todo = []
    for r in spec.runs:
        row = finished_row(out / r.name, r.params(), r.seed)
        if row is not None and (row["status"] == RunStatus.OK or not opts.retry_failed):
            rows[r.name] = row
        else:
            todo.append(r)
    kept = len(rows)
    order = {r.name: i for i, r in enumerate(spec.runs)}

    def ordered() -> list[dict[str, Any]]:
        return sorted(rows.values(), key=lambda row: order[row["run"]])

    t0 = now_s()
    write_results(out, ordered(), params)

    def report(last: str = "") -> None:
        if progress is None:
            return
        done = len(rows)
        elapsed = now_s() - t0
        ran = done - kept
        eta = elapsed / ran * (len(spec.runs) - done) if ran else None
        failed = sum(1 for row in rows.values() if row.get("status") != RunStatus.OK)
        progress(SweepProgress(len(spec.runs), done, kept, failed, elapsed, eta, last))

    interrupted = False
    if todo:
        log.info("%d of %d runs already finished in %s; running %d", kept, len(spec.runs), out, len(todo))
        token = uuid.uuid4().hex[:12]
        jobs = [
            RunJob(
                name=r.name,
                scenario=str(spec.scenario.resolve()),
                run_dir=str(out / r.name),
                seed=r.seed,
                sets=r.sets,
                params=json.loads(json.dumps(r.params(), default=str)),
                timeout_s=opts.run_timeout_s,
                stop_event=f"harness-sweep-stop-{token}",
                slots=opts.runs_per_worker if opts.scheduler else None,
            )
            for r in todo
        ]

        def on_row(row: dict[str, Any]) -> None:
            rows[row["run"]] = row
            write_results(out, ordered(), params)
            report(f"{row['run']}: {row.get('status')}")

        report()
        cluster = _Cluster(opts)
        with cluster as client:
            interrupted = _drive(client, jobs, token, on_row, report, clock)
            cluster.stopping = interrupted

    files = write_results(out, ordered(), params)
    return SweepOutcome(ordered(), len(rows) - kept, kept, interrupted, now_s() - t0, files)


def _drive(
    client: Any,
    jobs: list[RunJob],
    token: str,
    on_row: Callable[[dict[str, Any]], None],
    tick: Callable[[str], None],
    clock: Clock = WALL,
) -> bool:
    """Submit every job and hand each row to ``on_row`` as its run ends; True when stopped by Ctrl-C."""
    from distributed import Event, wait

    stop = Event(jobs[0].stop_event, client=client)
    futures = {
        client.submit(run_job, job, key=f"harness-run-{job.name}-{token}", pure=False, retries=0): job for job in jobs
    }
    pending = set(futures)

    def now_s() -> float:
        return clock.now_ns() / NS_PER_S

    last_seen = last_check = now_s()

    def collect(done: set[Any]) -> None:
        for fut in done:
            job = futures[fut]
            if fut.status == "finished":
                on_row(fut.result())
                continue
            exc = fut.exception() if fut.status == "error" else None
            on_row(
                {
                    "run": job.name,
                    "seed": job.seed,
                    **job.params,
                    "status": str(RunStatus.LOST),
                    "message": f"the Dask task failed: {exc!r}" if exc is not None else f"the Dask task {fut.status}",
                }
            )

    try:
        while pending:
            try:
                done, _ = wait(list(pending), timeout=1.0, return_when="FIRST_COMPLETED")
            except TimeoutError:  # distributed's wait raises instead of returning nothing done
                done = set()
            except CancelledError:  # the client lost its scheduler: Dask cancelled every future
                raise SimulationError(
                    f"lost the connection to the Dask scheduler; {len(pending)} run(s) did not finish "
                    "(their workers stopped them): re-run the same command to finish them"
                ) from None
            pending -= set(done)
            collect(set(done))
            if done:
                last_seen = now_s()
            elif now_s() - last_check > HEALTH_EVERY_S:
                last_check = now_s()
                note = _health(client)
                if note and now_s() - last_seen > SCHEDULER_LOST_S and client.status != "running":
                    raise SimulationError(f"{note} for {SCHEDULER_LOST_S:.0f} s: giving up ({len(pending)} runs left)")
                tick(note)
            else:
                tick("")
        return False
    except KeyboardInterrupt:
        log.warning("stopping the sweep: every running run gets SIGTERM")
        # Each call to the scheduler is bounded: a dead scheduler must not keep Ctrl-C from ending the sweep.
        _bounded(stop.set, 2.0)
        _bounded(lambda: wait(list(pending), timeout=STOP_WAIT_S), STOP_WAIT_S + 0.5)
        collect({f for f in pending if f.status in ("finished", "error")})
        _bounded(lambda: client.cancel(list(pending), force=True), 2.0)
        return True
    finally:
        if not pending:
            _bounded(stop.set, 2.0)  # nobody waits on it any more


def _health(client: Any) -> str:
    """Why nothing is happening, when it is the cluster's fault: no scheduler, or no worker."""
    if client.status != "running":
        return f"lost the Dask scheduler (client {client.status})"
    threads: dict[str, Any] = {}

    def ask() -> None:
        threads.update(client.nthreads())

    _bounded(ask, 5.0)
    return "" if threads else "waiting for a Dask worker to join the scheduler"


class _Cluster:
    """A client: to ``opts.scheduler``, or to a local cluster in this process (closed at the end)."""

    def __init__(self, opts: SweepOptions) -> None:
        self.opts = opts
        self.cluster: Any = None
        self.client: Any = None
        self.stopping = False
        """Stopped by Ctrl-C: close in a hurry (see ``CLOSE_STOPPING_S``)."""

    def __enter__(self) -> Any:
        from distributed import Client, LocalCluster

        if self.opts.scheduler:
            try:
                self.client = Client(self.opts.scheduler, timeout=15)
            except (OSError, ValueError) as exc:
                raise ScenarioError(f"--scheduler {self.opts.scheduler}: cannot connect ({exc})") from None
            return self.client
        threads = self.opts.runs_per_worker or os.cpu_count() or 1
        # Threads, not processes: a task only starts a subprocess and waits for it. Ctrl-C then reaches
        # this process alone (the runs are in their own process groups) and the sweep stops them itself.
        self.cluster = LocalCluster(
            n_workers=1,
            threads_per_worker=threads,
            processes=False,
            dashboard_address=None,
            silence_logs=logging.INFO if log.isEnabledFor(logging.INFO) else logging.ERROR,
        )
        self.client = Client(self.cluster)
        return self.client

    def __exit__(self, *exc: object) -> None:
        bound = CLOSE_STOPPING_S if self.stopping else CLOSE_S
        if self.client is not None:
            _bounded(lambda: self.client.close(timeout=bound), bound)
        if self.cluster is not None:
            _bounded(lambda: self.cluster.close(timeout=bound), bound)


def _bounded(call: Callable[[], object], timeout_s: float) -> None:
    """Run ``call`` for at most ``timeout_s`` (in a daemon thread); errors and overruns are logged, not raised."""
    failure: list[BaseException] = []

    def target() -> None:
        try:
            call()
        except BaseException as exc:  # reported below; the shutdown goes on
            failure.append(exc)

    t = threading.Thread(target=target, name="sweep-shutdown", daemon=True)
    t.start()
    t.join(timeout_s)
    if t.is_alive():
        log.warning("the scheduler did not answer within %.0f s; going on without it", timeout_s)
    elif failure and not isinstance(failure[0], TimeoutError):
        log.debug("shutdown step failed: %r", failure[0])
