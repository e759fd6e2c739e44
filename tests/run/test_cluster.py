"""One ``harness run --scheduler`` over a Dask cluster's workers (issue 35).

The root (``harness run`` and the Dask scheduler) is one network namespace, the two Dask workers another,
joined by a veth pair, as ``tests/run/test_tree.py`` makes its two hosts: each side has its own loopback, so a
worker's MAVLink ports and child channel are its own, and the root channel is reached over the veth. Where
namespaces cannot be made (no CAP_NET_ADMIN), the workers are plain processes of this machine.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from harness.record.world import read_topics
from tests.helpers import TwoHosts, free_port_on, two_hosts

MISSION = Path(__file__).resolve().parents[2] / "missions" / "hover.py"
HOVER_S = "3"
VEHICLES = 6
SEED = 11
pytestmark = pytest.mark.sim
DASK = str(Path(sys.executable).with_name("dask"))


@dataclass
class Cluster:
    root_prefix: tuple[str, ...]
    scheduler: str
    workers: dict[str, subprocess.Popen[bytes]]
    """By address (``tcp://IP:PORT``)."""


def _listening(prefix: tuple[str, ...], ip: str, port: int, timeout_s: float) -> None:
    code = f"import socket; socket.create_connection(({ip!r}, {port}), timeout=1).close()"
    end = time.monotonic() + timeout_s
    while subprocess.run([*prefix, sys.executable, "-c", code], capture_output=True).returncode != 0:
        assert time.monotonic() < end, f"nothing listens on {ip}:{port}"
        time.sleep(0.5)


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[Cluster]:
    with two_hosts("10.232.0", ("127.0.0.1", "127.0.0.1")) as hosts:
        yield from _cluster(tmp_path, hosts)


def _cluster(tmp_path: Path, hosts: TwoHosts) -> Iterator[Cluster]:
    root_ip, worker_ip, root_prefix, worker_prefix = hosts.a_ip, hosts.b_ip, hosts.a_prefix, hosts.b_prefix
    procs: list[subprocess.Popen[bytes]] = []
    try:
        port = free_port_on(root_prefix, root_ip)
        scheduler = f"tcp://{root_ip}:{port}"
        log = (tmp_path / "scheduler.log").open("wb")
        procs.append(
            subprocess.Popen(
                [*root_prefix, DASK, "scheduler", "--host", root_ip, "--port", str(port), "--no-dashboard"],
                stdout=log,
                stderr=log,
                start_new_session=True,
            )
        )
        _listening(root_prefix, root_ip, port, 60)
        workers = {}
        for k in range(2):
            wport = free_port_on(worker_prefix, worker_ip)
            wlog = (tmp_path / f"worker-{k}.log").open("wb")
            proc = subprocess.Popen(
                [
                    *worker_prefix,
                    DASK,
                    "worker",
                    scheduler,
                    "--host",
                    worker_ip,
                    "--worker-port",
                    str(wport),
                    "--nthreads",
                    "1",
                    "--no-nanny",
                    "--no-dashboard",
                    "--memory-limit",
                    "2GB",
                ],
                stdout=wlog,
                stderr=wlog,
                start_new_session=True,
            )
            procs.append(proc)
            workers[f"tcp://{worker_ip}:{wport}"] = proc
        for addr in workers:
            _listening(worker_prefix, worker_ip, int(addr.rsplit(":", 1)[1]), 60)
        yield Cluster(root_prefix, scheduler, workers)
    finally:
        for proc in procs:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)


class Root:
    """``harness run --scheduler`` in the root's namespace; its progress lines are collected as they come."""

    def __init__(self, cluster: Cluster, out: Path, hover_s: str = HOVER_S) -> None:
        argv = [sys.executable, "-m", "harness.cli", "run", "--vehicles", str(VEHICLES), "--mission", str(MISSION)]
        argv += ["--seed", str(SEED), "--scheduler", cluster.scheduler, "--out", str(out), "--", hover_s]
        self.proc = subprocess.Popen(
            [*cluster.root_prefix, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        self.lines: list[str] = []
        self.flying = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line)
            if f"armed {VEHICLES}/{VEHICLES}" in line:
                self.flying.set()

    def wait(self, timeout: float) -> tuple[int, str]:
        assert self.proc.stdout is not None
        out = self.proc.stdout.read()
        code = self.proc.wait(timeout)
        self._reader.join(5)
        return code, out + "".join(self.lines)


def _tracks(run: Path) -> dict[str, list[object]]:
    """Every vehicle's recorded samples (state, pose, fix), without the wall-clock date of the run's start
    that the pose and fix messages carry (their sim time is in the state's ``t_s``)."""
    topics = read_topics(run / "world.mcap")
    return {
        t: [{k: v for k, v in m.items() if k != "timestamp"} for m in msgs]
        for t, msgs in topics.items()
        if t.startswith("/vehicle/")
    }


def _leftovers() -> list[str]:
    """Processes of a share still running anywhere on this machine (every namespace shares its pids)."""
    out = subprocess.run(["ps", "-eo", "pid,args"], capture_output=True, text=True).stdout
    return [line for line in out.splitlines() if "harness.run.share" in line or "harness-share-" in line]


def _no_leftovers(within_s: float) -> None:
    end = time.monotonic() + within_s
    while _leftovers() and time.monotonic() < end:
        time.sleep(0.2)
    assert not _leftovers(), _leftovers()


def test_six_vehicles_on_two_workers_fly_as_on_one_machine(cluster: Cluster, tmp_path: Path) -> None:
    root = Root(cluster, tmp_path / "cluster")
    code, text = root.wait(900)
    assert code == 0, text
    argv = [sys.executable, "-m", "harness.cli", "run", "--vehicles", str(VEHICLES), "--mission", str(MISSION)]
    argv += ["--seed", str(SEED), "--workers", "1", "--no-progress", "--out", str(tmp_path / "one"), "--", HOVER_S]
    one = subprocess.run(
        argv,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert one.returncode == 0, one.stdout + one.stderr
    summary = json.loads((tmp_path / "cluster" / "summary.json").read_text())
    hosts = [v["host"] for v in summary["vehicles"]]
    assert set(hosts) == set(cluster.workers), hosts  # both workers flew vehicles, and the summary says which
    assert [v["mission_exit_code"] for v in summary["vehicles"]] == [0] * VEHICLES
    for v in summary["vehicles"]:
        assert v["max_altitude_m"] > 3.0 and v["landed"]
    workers = summary["cluster"]["workers"]
    assert {w["worker"] for w in workers} == set(cluster.workers)
    assert all(w["ticks"] > 0 and w["ms_per_tick"] > 0 and w["cpu_s"] > 0 for w in workers), workers
    # the recordings of the workers are in the root's run directory
    for i in range(VEHICLES):
        assert (tmp_path / "cluster" / f"vehicle-{i}.tlog").stat().st_size > 10_000
        assert (tmp_path / "cluster" / f"mission-{i}.stdout").is_file()
    # the same seed on one machine: every vehicle's ground truth, sample for sample, to the run's last tick. A
    # remote mission's exit is part of the lockstep: its BYE answers its phase 0 on its child channel, which
    # reports it up (ANNOUNCE) before its own END-TICK-0 of that tick, so the root, whose tick waits for that
    # answer, ends at the same tick as on one machine whenever the messages arrive.
    one_summary = json.loads((tmp_path / "one" / "summary.json").read_text())
    assert summary["sim_time_s"] == one_summary["sim_time_s"], (summary["sim_time_s"], one_summary["sim_time_s"])
    ours, theirs = _tracks(tmp_path / "cluster"), _tracks(tmp_path / "one")
    assert sorted(ours) == sorted(theirs)
    for topic in sorted(theirs):
        assert len(ours[topic]) == len(theirs[topic]) > 900, (topic, len(ours[topic]), len(theirs[topic]))
        assert ours[topic] == theirs[topic], topic
    last = theirs["/vehicle/0/state"][-1]
    assert last["on_ground"] and last["t_s"] == pytest.approx(summary["sim_time_s"], abs=0.02)
    _no_leftovers(5)


def test_ctrl_c_ends_the_run_and_every_share(cluster: Cluster, tmp_path: Path) -> None:
    root = Root(cluster, tmp_path / "run", "120")  # hover long: Ctrl-C comes while they fly
    try:
        assert root.flying.wait(600), "".join(root.lines)
        assert _leftovers()
        t0 = time.monotonic()
        root.proc.send_signal(signal.SIGINT)
        code, text = root.wait(60)
        took = time.monotonic() - t0
    finally:
        root.proc.kill()
    assert code == 130, text
    assert took < 20, took
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["status"] == "interrupted"
    _no_leftovers(5)


def test_a_killed_worker_ends_the_run_naming_it(cluster: Cluster, tmp_path: Path) -> None:
    root = Root(cluster, tmp_path / "run", "120")
    try:
        assert root.flying.wait(600), "".join(root.lines)
        victim = sorted(cluster.workers)[1]
        t0 = time.monotonic()
        os.killpg(cluster.workers[victim].pid, signal.SIGKILL)
        code, text = root.wait(60)
        took = time.monotonic() - t0
    finally:
        root.proc.kill()
    assert code == 1, text
    assert took < 20, took
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["status"] == "failed"
    assert victim.removeprefix("tcp://") in summary["message"], summary["message"]
    assert victim.removeprefix("tcp://") in text
    _no_leftovers(5)
