"""``harness run --cluster local:K`` / ``--scheduler tcp://HOST:8786``: one run over a Dask cluster's workers.

The root stays in ``harness run``: it simulates the physics and records the ground truth of every vehicle,
as for ``harness run --remote-vehicles`` (``docs/tree.md``). Each Dask worker gets a *share* of the vehicles
(contiguous, none empty) as one long-lived task, :func:`harness.run.share.fly_share`: a child channel joined
to the root with the share's autopilots, MAVLink servers and missions — what ``harness join`` runs by hand.

- **Split**: by each worker's cores (``nthreads``) over its measured cost of a unit of work
  (:func:`probe`, timed on the worker); :func:`split`.
- **Capacity**: what each worker's memory holds (``memory_limit``, at :data:`WORKER_MB` +
  :data:`SHARE_VEHICLE_MB` per vehicle, + :data:`SHARE_MISSION_MB` per mission) and its MAVLink ports;
  ``--vehicles`` above the sum is one line before anything starts.
- **Secret**: generated for the run; the root channel requires it and each task carries it (over Dask's
  comm, to the share process through a pipe): never on a command line or in a file.
- **Ending**: the root's channel ends every share at the end of the run; a share that fails or a worker that
  leaves fails the run naming it (the child channel's name is ``dask-worker <address>``); Ctrl-C and any
  failure set the run's stop event, and every task stops its share's process group (SIGTERM, then SIGKILL).
- **Files**: the missions' directories travel in each task (a tar); each share's recordings (tlogs, ULogs,
  mission output) come back in its result and are unpacked into the root's run directory.
"""

from __future__ import annotations

import io
import logging
import math
import os
import re
import secrets
import signal
import socket
import tarfile
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from harness.core.endpoints import SYSIDS_PER_LINK
from harness.core.errors import ScenarioError, SimulationError
from harness.run.ports import PX4_API_BASE
from harness.run.share import ShareJob, fly_share
from harness.scenario.plan import MissionPlan

log = logging.getLogger(__name__)

WORKER_MB = 250
"""A share's own processes: ``harness.run.share`` with its child channel and the autopilot host's Python."""
SHARE_VEHICLE_MB = 4
"""Each vehicle in a share's autopilot host (autopilot, MAVLink server, tlog buffers)."""
SHARE_MISSION_MB = 80
"""A mission process (``harness.scenario.limits.PER_MISSION_MB``)."""
MAX_BUNDLE_BYTES = 64 << 20
"""The missions' files travel in every task: a mission directory bigger than this is refused (one line)."""
STOP_WAIT_S = 5.0
"""At the end of the run, how long the root waits for the shares' results (their recordings)."""
CLOSE_S = 4.0
_LOCAL = re.compile(r"^local:(\d+)$")
_ADDRESS = re.compile(r"^([a-z]+://)?([^\s:/]+):(\d+)$")


def parse_cluster(text: str) -> int:
    """``--cluster local:K``: K worker processes (K >= 1)."""
    m = _LOCAL.match(text)
    if m is None or int(m.group(1)) < 1:
        raise ScenarioError(f"--cluster must be local:K with K >= 1 worker processes, got {text!r}")
    return int(m.group(1))


def check_scheduler(text: str) -> str:
    if not _ADDRESS.match(text):
        raise ScenarioError(f"--scheduler {text}: expected a Dask scheduler address like tcp://HOST:8786")
    return text


@dataclass(frozen=True)
class WorkerInfo:
    address: str
    host: str
    nthreads: int
    memory_mb: int | None
    """``memory_limit`` (None: unlimited; the machine's available memory is then the limit)."""
    unit_s: float = 1.0
    """Wall seconds of :func:`probe` on the worker (its cost per unit of work)."""


def capacity(w: WorkerInfo, mission_share: float) -> int:
    """How many vehicles ``w`` holds: its memory (each vehicle, and a mission for the fraction
    ``mission_share`` of them) and its MAVLink ports (``PX4_API_BASE`` + i up to 65535)."""
    ports = 65535 - PX4_API_BASE
    if w.memory_mb is None:
        return ports
    per = SHARE_VEHICLE_MB + SHARE_MISSION_MB * mission_share
    return max(0, min(ports, int((w.memory_mb - WORKER_MB) / per)))


def split(vehicles: int, workers: Sequence[WorkerInfo], mission_share: float = 0.0) -> list[tuple[WorkerInfo, range]]:
    """Vehicles 0…n-1 over ``workers`` in contiguous shares proportional to their cores over their measured
    cost, largest remainders first, none over its capacity; workers left with no vehicle get no share."""
    caps = [capacity(w, mission_share) for w in workers]
    fastest = min(w.unit_s for w in workers)
    # each worker's cost relative to the fastest, in steps of a half: a difference below a quarter is a shared
    # machine's noise (two identical workers measured 1.2x apart under load), not a slower core
    weights = [w.nthreads / max(1.0, round(2 * w.unit_s / fastest) / 2) for w in workers]
    total = sum(weights)
    exact = [vehicles * weight / total for weight in weights]
    sizes = [min(cap, math.floor(x)) for cap, x in zip(caps, exact, strict=True)]
    order = sorted(range(len(workers)), key=lambda k: exact[k] - math.floor(exact[k]), reverse=True)
    while sum(sizes) < vehicles:
        room = [k for k in order if sizes[k] < caps[k]]
        if not room:
            raise ScenarioError(f"--vehicles {vehicles}: the cluster holds {sum(caps)}")  # checked before
        for k in room[: vehicles - sum(sizes)]:
            sizes[k] += 1
    out, start = [], 0
    for w, size in zip(workers, sizes, strict=True):
        if size:
            out.append((w, range(start, start + size)))
            start += size
    return out


def probe(rounds: int = 7) -> float:
    """A fixed unit of Python work (float arithmetic, as a vehicle's step is), timed on the worker: its cost
    relative to the others'. The best of ``rounds``: what the core does when it gets to run (a shared machine's
    other load would otherwise skew the split from one start to the next)."""
    best = math.inf
    for _ in range(rounds):
        t0 = time.perf_counter()
        acc = 0.0
        for i in range(50_000):
            acc += (i * 0.5) ** 0.5
        best = min(best, time.perf_counter() - t0 + 0.0 * acc)
    return best


def bundle(missions: Sequence[MissionPlan | None]) -> tuple[bytes, list[tuple[str, tuple[str, ...]] | None]]:
    """The missions' directories as one gzipped tar (each under ``d<k>/``), and each mission's script
    relative to it; one line when the directories are too big to travel with a task."""
    dirs: dict[Path, str] = {}
    rel: list[tuple[str, tuple[str, ...]] | None] = []
    for m in missions:
        if m is None:
            rel.append(None)
            continue
        d = m.script.resolve().parent
        name = dirs.setdefault(d, f"d{len(dirs)}")
        rel.append((f"{name}/{m.script.name}", tuple(m.args)))
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        for d, name in dirs.items():
            tar.add(d, arcname=name, filter=_skip_caches)
    data = buf.getvalue()
    if len(data) > MAX_BUNDLE_BYTES:
        raise ScenarioError(
            f"--mission: the mission directories {sorted(str(d) for d in dirs)} are {len(data) >> 20} MB compressed "
            f"(at most {MAX_BUNDLE_BYTES >> 20} MB travel with each worker's task): keep a mission's directory small"
        )
    return data, rel


def _skip_caches(info: tarfile.TarInfo) -> tarfile.TarInfo | None:
    parts = Path(info.name).parts
    return None if "__pycache__" in parts or any(p.startswith(".") for p in parts[1:]) else info


def own_address(scheduler: str | None) -> str:
    """This machine's address as the cluster's workers reach it: loopback for a local cluster, else the
    address of the interface that routes to the scheduler."""
    if scheduler is None:
        return "127.0.0.1"
    m = _ADDRESS.match(scheduler)
    assert m is not None
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect((m.group(2), int(m.group(3))))
            return str(s.getsockname()[0])
        except OSError as exc:
            raise ScenarioError(f"--scheduler {scheduler}: no route to it ({exc})") from None


class ClusterShares:
    """The root's side of a cluster run (:class:`harness.run.launcher.Remote`): the Dask client, the shares,
    their tasks, their results."""

    def __init__(
        self,
        workers: int | None,
        scheduler: str | None,
        vehicles: int,
        missions: Sequence[MissionPlan | None],
        firmware: str = "px4",
        progress: Callable[[str], None] | None = None,
        physics_on_workers: bool = True,
    ) -> None:
        self.local_workers = workers
        self.scheduler = scheduler
        self.vehicles = vehicles
        self.mission_plans = list(missions) + [None] * (vehicles - len(missions))
        self.missions = sum(m is not None for m in self.mission_plans)
        """Mission processes over all the shares."""
        self.firmware = firmware
        self.progress = progress
        self.physics_on_workers = physics_on_workers
        """Each share steps its vehicles' physics (the root is asked only at phase ticks): what scales."""
        self.secret = secrets.token_hex(24)
        self.token = uuid.uuid4().hex[:12]
        self.host = own_address(scheduler)
        self.listen = f"tcp://{self.host}:0"
        """The root channel listens here (the port is the kernel's choice; the tasks get the bound address)."""
        self.cluster: Any = None
        self.client: Any = None
        self.shares: list[tuple[WorkerInfo, range]] = []
        self.futures: list[Any] = []
        self.results: list[dict[str, Any]] = []
        self._stop: Any = None
        self._bundle, self._rel = bundle(self.mission_plans)

    # -- before the run -------------------------------------------------------------------------------------

    def open(self) -> None:
        """Connect (or start the local cluster), measure the workers, split the vehicles; one line when the
        cluster cannot hold them."""
        from distributed import Client, Event

        _quiet_dask()
        if self.scheduler is not None:
            try:
                self.client = Client(self.scheduler, timeout=15)
            except (OSError, ValueError) as exc:
                raise ScenarioError(f"--scheduler {self.scheduler}: cannot connect ({exc})") from None
            try:
                self.client.wait_for_workers(1, timeout=60)
            except (TimeoutError, OSError):
                raise ScenarioError(f"--scheduler {self.scheduler}: no Dask worker joined within 60 s") from None
        else:
            assert self.local_workers is not None
            cores = len(os.sched_getaffinity(0))
            # the worker processes start with Ctrl-C ignored (a terminal's Ctrl-C reaches the whole process
            # group: they would die with a traceback each; the run stops them itself), restored here after
            previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
            try:
                self.cluster = self._local_cluster(cores)
            finally:
                signal.signal(signal.SIGINT, previous)
            self.client = Client(self.cluster)
        self._stop = Event(f"harness-run-stop-{self.token}", client=self.client)
        workers = self.workers()
        mission_share = self.missions / max(1, self.vehicles)
        held = sum(capacity(w, mission_share) for w in workers)
        if self.vehicles > held:
            raise ScenarioError(
                f"--vehicles {self.vehicles}: the cluster's {len(workers)} worker(s) hold {held} vehicles "
                f"({'with' if mission_share else 'without'} missions; by their memory_limit and ports)"
            )
        self.shares = split(self.vehicles, workers, mission_share)
        if self.progress is not None:
            for w, r in self.shares:
                procs = max(w.nthreads, -(-len(r) // SYSIDS_PER_LINK))
                self.progress(
                    f"cluster: worker {w.address} ({w.host}, {w.nthreads} cores): vehicles {r.start}-{r.stop - 1} "
                    f"in {procs} autopilot process(es), each with a ground-station port of its own on that machine "
                    "(summary.json: cluster.workers[].gcs_ports)"
                )

    def _local_cluster(self, cores: int) -> Any:
        from distributed import LocalCluster

        assert self.local_workers is not None
        return LocalCluster(
            n_workers=self.local_workers,
            threads_per_worker=max(1, cores // self.local_workers),
            processes=True,
            dashboard_address=":0",  # (None is 8787, and a warning on stderr when another cluster has it)
            silence_logs=logging.CRITICAL,
        )

    def workers(self) -> list[WorkerInfo]:
        """The cluster's workers, each with its cost per unit of work measured on it (:func:`probe`)."""
        info = self.client.scheduler_info()["workers"]
        timed = self.client.run(probe)
        out = []
        for addr in sorted(info):
            w = info[addr]
            mem = w.get("memory_limit") or 0
            host = str(w.get("host") or addr)
            out.append(WorkerInfo(addr, host, int(w["nthreads"]), int(mem) >> 20 or None, float(timed.get(addr, 1.0))))
        return out

    def host_of(self, vehicle: int) -> str:
        for w, r in self.shares:
            if vehicle in r:
                return w.address
        return ""

    def share_name(self, w: WorkerInfo) -> str:
        """The share's child channel's name: every message about it names the worker."""
        return f"dask-worker {w.address}"

    # -- the run ----------------------------------------------------------------------------------------------

    def start(self, address: str, physics: bytes = b"") -> None:
        """Submit every share's task, pinned to its worker (never moved: a lost worker fails the run)."""
        for w, r in self.shares:
            job = ShareJob(
                parent=address,
                first=r.start,
                vehicles=len(r),
                name=self.share_name(w),
                secret=self.secret,
                bundle=self._bundle,
                missions=tuple(self._rel[r.start : r.stop]),
                firmware=self.firmware,
                stop_event=f"harness-run-stop-{self.token}",
                physics=physics if self.physics_on_workers else b"",
                processes=w.nthreads,
            )
            self.futures.append(
                self.client.submit(
                    fly_share,
                    job,
                    key=f"harness-share-{r.start}-{self.token}",
                    workers=[w.address],
                    allow_other_workers=False,
                    pure=False,
                    retries=0,
                )
            )

    def check(self) -> None:
        """Raise (naming the worker) when a share's task ended before the run. (A worker that dies takes its
        share's processes along: the root channel sees that child's connection break and names it.)"""
        for (w, r), fut in zip(self.shares, self.futures, strict=False):
            what = f"cluster worker {self.share_name(w)} (vehicles {r.start}-{r.stop - 1})"
            if fut.status == "error":
                raise SimulationError(f"{what}: its task failed: {fut.exception()!r}")
            if fut.status == "finished":
                res = fut.result()
                raise SimulationError(f"{what}: its share ended early: {res.get('message') or res.get('exit_code')}")
            if fut.status == "cancelled":
                raise SimulationError(f"{what}: its task was cancelled")

    def stop(self, run_dir: Path, hurry: bool) -> None:
        """The run is over (its channel told every share so): the shares' results collected (their recordings
        into ``run_dir``) — after ``STOP_WAIT_S`` at most, or at once when ``hurry`` (the run failed or was
        interrupted) — every share still running stopped, the tasks cancelled, the client (and a local
        cluster) closed."""
        from distributed import wait

        if self.client is None:
            return
        if self.futures and not hurry:
            _bounded(lambda: wait(self.futures, timeout=STOP_WAIT_S), STOP_WAIT_S + 0.5)
        if self._stop is not None:
            _bounded(self._stop.set, 2.0)
        if self.futures:
            _bounded(lambda: wait(self.futures, timeout=STOP_WAIT_S), STOP_WAIT_S + 0.5)
            for fut in self.futures:
                if fut.status == "finished":
                    res = fut.result()
                    _unpack(res.pop("files", b""), run_dir, res["name"])
                    self.results.append(res)
            _bounded(lambda: self.client.cancel(self.futures, force=True), 2.0)
        _bounded(lambda: self.client.close(timeout=CLOSE_S), CLOSE_S)
        if self.cluster is not None:
            _bounded(lambda: self.cluster.close(timeout=CLOSE_S), CLOSE_S)

    def summary(self, ticks: int) -> dict[str, Any]:
        """``summary.json``'s ``cluster``: each worker's share, its timing over the run's ``ticks`` and CPU time."""
        results = {r["name"]: r for r in self.results}
        workers = []
        for w, r in self.shares:
            res = results.get(self.share_name(w), {})
            cpu, wall = float(res.get("cpu_s", 0.0)), float(res.get("tick_wall_s", 0.0))
            workers.append(
                {
                    "worker": w.address,
                    "host": w.host,
                    "nthreads": w.nthreads,
                    "probe_s": w.unit_s,
                    "vehicles": [r.start, r.stop - 1],
                    "ticks": ticks,
                    "tick_wall_s": wall,
                    "ms_per_tick": 1e3 * wall / ticks if ticks else 0.0,
                    "cpu_s": cpu,
                    "cpu_us_per_vehicle_tick": 1e6 * cpu / (ticks * len(r)) if ticks else 0.0,
                    "max_rss_mb": res.get("max_rss_mb", 0.0),
                    "gcs_ports": res.get("gcs_ports", []),
                    "exit_code": res.get("exit_code"),
                    "message": res.get("message", "no result (the task did not finish)"),
                }
            )
        return {"cluster": {"scheduler": self.scheduler or f"local:{self.local_workers}", "workers": workers}}


def _unpack(data: bytes, run_dir: Path, share: str) -> None:
    """A share's files into the run directory: per-vehicle files under their own names (``vehicle-3.tlog``,
    ``mission-3.stdout``), the share's others prefixed with its worker (``worker-…-autopilot.stderr``)."""
    if not data:
        return
    prefix = "worker-" + re.sub(r"[^A-Za-z0-9._-]+", "_", share).strip("_") + "-"
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
        for member in tar.getmembers():
            if not member.isfile():
                continue
            name = Path(member.name).name
            if not re.match(r"^(vehicle|mission)-\d+[.-]", name):
                name = prefix + name
            src = tar.extractfile(member)
            if src is not None:
                (run_dir / name).write_bytes(src.read())


def _quiet_dask() -> None:
    import distributed  # noqa: F401  (its loggers exist once it is imported)

    names = [n for n in logging.root.manager.loggerDict if n == "distributed" or n.startswith("distributed.")]
    for name in ["distributed", *names]:
        logging.getLogger(name).setLevel(logging.CRITICAL)


def _bounded(call: Callable[[], object], timeout_s: float) -> None:
    """``call`` for at most ``timeout_s`` (a daemon thread): a dead scheduler must not hold up the run's end."""
    t = threading.Thread(target=lambda: _quietly(call), name="cluster-shutdown", daemon=True)
    t.start()
    t.join(timeout_s)


def _quietly(call: Callable[[], object]) -> None:
    try:
        call()
    except BaseException as exc:  # the shutdown goes on
        log.debug("cluster shutdown step failed: %r", exc)
