"""One Dask worker's share of a ``harness run --cluster``/``--scheduler`` run: a child channel of the root.

:func:`fly_share` is the Dask task (long-lived: it lasts the run). On the worker it unpacks the missions'
files that came with the task into a temporary directory and starts ``python -m harness.run.share`` — what
``harness join`` runs (:func:`harness.run.join.run_join`): a child channel joined to the root, the share's
autopilots and MAVLink servers, and its missions on the sim clock — in its own process group, tied to the
worker process (:mod:`harness.core.lifeline`): a worker that dies takes it and its children along. The
configuration, the run's secret with it, goes to that process through a pipe on its stdin: never on a command
line, never in a file.

The task ends when the share process ends (the root ended the run, or the share failed), or when the run's
stop event is set (the root stopped: Ctrl-C, a failure elsewhere): then the process group gets SIGTERM, and
SIGKILL after :data:`STOP_GRACE_S`. It returns what the root needs: the share's outcome, its tick timing
and CPU time, and its recordings (tlogs, ULogs, the missions' output) as a tar archive in the result.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import resource
import signal
import socket
import subprocess
import sys
import tarfile
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from harness.core import lifeline

STOP_GRACE_S = 3.0
"""After the stop event or the task's cancellation, how long the share's processes have for SIGTERM."""
POLL_S = 0.25
RESULT_FILE = "share.json"
"""What the share process writes into its output directory at its end (outcome and tick timing)."""


@dataclass(frozen=True)
class ShareJob:
    """One worker's share: vehicles ``first … first + vehicles - 1`` of the run."""

    parent: str
    """The root channel's address."""
    first: int
    vehicles: int
    name: str
    """This share's child channel's name in the run (it names the worker in every message)."""
    secret: str
    """The run's channel secret (generated for the run; travels in the task, over Dask's comm)."""
    bundle: bytes
    """The missions' files: a gzipped tar whose top directories the ``missions`` paths are relative to."""
    missions: tuple[tuple[str, tuple[str, ...]] | None, ...]
    """Per vehicle of the share: its mission's script (relative to the bundle) and arguments, or None."""
    firmware: str
    stop_event: str
    """The Dask ``Event`` the root sets when the run stops."""
    physics: bytes = b""
    """The run's ``physics.json``: the share steps its vehicles' physics too (empty: the root does)."""
    processes: int = 1
    """Autopilot processes of the share (the worker's cores; more for over 244 vehicles)."""


def fly_share(job: ShareJob) -> dict[str, Any]:
    """The Dask task: fly ``job`` until the run ends; the outcome (see the module's doc)."""
    from distributed import Event, get_worker

    worker = get_worker()
    stop = Event(job.stop_event)
    wall0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="harness-share-") as tmp:
        root = Path(tmp)
        with tarfile.open(fileobj=io.BytesIO(job.bundle), mode="r:gz") as tar:
            tar.extractall(root / "missions", filter="data")
        out = root / "out"
        out.mkdir()
        if job.physics:
            (out / "physics.json").write_bytes(job.physics)
        config = dict(
            asdict(job), bundle="", physics=bool(job.physics), missions_dir=str(root / "missions"), out=str(out)
        )
        proc = subprocess.Popen(
            [sys.executable, "-m", "harness.run.share"],
            stdin=subprocess.PIPE,
            stdout=(out / "share.stdout").open("wb"),
            stderr=(out / "share.stderr").open("wb"),
            env=lifeline.tied_env(os.environ),
            process_group=0,
            cwd=tmp,
        )
        assert proc.stdin is not None
        proc.stdin.write(json.dumps(config).encode())
        proc.stdin.close()
        stopped = ""
        try:
            while proc.poll() is None:
                if stop.wait(POLL_S):
                    stopped = "the root stopped the run"
                    break
        finally:  # also when Dask cancels the task (an exception raised into this thread)
            code = _end(proc)
        result: dict[str, Any] = {}
        with contextlib.suppress(OSError, ValueError):
            result = json.loads((out / RESULT_FILE).read_text())
        return {
            "name": job.name,
            "worker": worker.address,
            "host": socket.gethostname(),
            "vehicles": [job.first, job.first + job.vehicles - 1],
            "exit_code": code,
            "stopped": stopped,
            "wall_s": time.monotonic() - wall0,
            **result,
            "files": _pack(out),
        }


def _end(proc: subprocess.Popen[bytes]) -> int:
    """Stop the share's process group if it still runs; its exit code."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(STOP_GRACE_S)
        except subprocess.TimeoutExpired:
            pass
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)  # whatever of the group is left: nothing outlives the task
    return proc.wait()


RECORDINGS = (".tlog", ".ulg", ".stdout", ".stderr", ".json", ".bin")


def _pack(out: Path) -> bytes:
    """The share's recordings and outputs, as a gzipped tar (what the root unpacks into its run directory)."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz", compresslevel=1) as tar:
        for path in sorted(out.rglob("*")):
            if path.is_file() and path.suffix in RECORDINGS and path.name != "physics.json":
                tar.add(path, arcname=str(path.relative_to(out)))
    return buf.getvalue()


def _main() -> int:
    """``python -m harness.run.share``: the share process (its configuration, with the secret, on stdin)."""
    lifeline.hold_on()
    from harness.autopilot.firmware import Firmware
    from harness.core.errors import ScenarioError, SimulationError, StopSignal
    from harness.run.join import JoinPlan, run_join
    from harness.scenario.plan import MissionPlan

    def handler(signum: int, _frame: object) -> None:
        raise StopSignal(signum)

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    cfg = json.loads(sys.stdin.buffer.read())
    out = Path(cfg["out"])
    base = Path(cfg["missions_dir"])
    missions = tuple(None if m is None else MissionPlan(base / m[0], tuple(m[1])) for m in cfg["missions"])
    plan = JoinPlan(
        parent=cfg["parent"],
        first_vehicle=cfg["first"],
        vehicles=cfg["vehicles"],
        out=out,
        missions=missions,
        secret=cfg["secret"].encode(),
        name=cfg["name"],
        firmware=Firmware.parse(cfg["firmware"], "firmware"),
        physics=str(out / "physics.json") if cfg.get("physics") else None,
        processes=int(cfg.get("processes", 1)),
    )
    outcome: dict[str, Any]
    try:
        result = run_join(plan)
        outcome = {"message": result.message, "exits": {str(k): v for k, v in result.exits.items()}}
        outcome |= result.timing
        outcome["gcs_ports"] = [{"port": g, "vehicles": [a, b]} for g, a, b in result.gcs_ports]
        code = result.exit_code
    except (ScenarioError, SimulationError) as exc:
        outcome, code = {"message": str(exc), "exits": {}}, 1
    except KeyboardInterrupt:
        outcome, code = {"message": "stopped", "exits": {}}, 130
    used = [resource.getrusage(who) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)]
    outcome["cpu_s"] = sum(u.ru_utime + u.ru_stime for u in used)  # its autopilots and missions: waited for
    outcome["max_rss_mb"] = max(u.ru_maxrss for u in used) / 1024
    (out / RESULT_FILE).write_text(json.dumps(outcome))
    return code


if __name__ == "__main__":
    lifeline.exit_now(_main())
