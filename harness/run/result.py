"""What a run reports: its status and the per-vehicle summary written to ``summary.json``."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from harness.core.files import RecordingError
from harness.record.status import KILLED, RUNNING, write_final_json


class RunStatus(enum.StrEnum):
    """A run's outcome: ``summary.json``'s ``status`` (running while it runs, then ok, failed, interrupted;
    killed when read back from a run whose process is gone), and in a sweep's results.csv also what the sweep
    saw of a run that wrote no summary (timeout, lost)."""

    RUNNING = RUNNING
    """Written from the start and every second while the run goes on (:mod:`harness.record.status`)."""
    OK = "ok"
    FAILED = "failed"
    INTERRUPTED = "interrupted"
    TIMEOUT = "timeout"
    KILLED = KILLED
    """``harness run`` was killed (``kill -9``, the OOM killer) after it started: its summary still said "running"."""
    LOST = "lost"
    """``harness run`` ended without writing a summary (a crash before it started)."""


@dataclass
class VehicleSummary:
    id: int
    mission: str | None
    mission_exit_code: int | None = None
    """As the mission ended: its exit code, or minus the signal that killed it (``-9``); -1 when the channel
    dropped it while it ran on; None while it still ran when the run ended."""
    mission_exit_reason: str = ""
    """How it ended, in words (``script exited with 0``, ``killed by SIGKILL``, ``dropped: stalled ...``)."""
    max_altitude_m: float = 0.0
    final_position_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    landed: bool = True
    armed: bool = False
    crashed: bool = False
    host: str | None = None
    """The cluster worker that flew it (``harness run --cluster``); None: this machine."""


@dataclass
class RunResult:
    status: RunStatus
    sim_time_s: float
    wall_time_s: float
    vehicles: list[VehicleSummary]
    faults: list[dict[str, Any]]
    message: str = ""
    incomplete: list[str] = field(default_factory=list)
    """The run's files that could not be completed (a full disk): ``incomplete_files`` in ``summary.json``."""

    @property
    def real_time_factor(self) -> float:
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else 0.0

    @property
    def exit_code(self) -> int:
        return 0 if self.status == RunStatus.OK else (130 if self.status == RunStatus.INTERRUPTED else 1)

    def to_json(self) -> dict[str, Any]:
        return {
            "status": self.status,
            "message": self.message,
            "sim_time_s": self.sim_time_s,
            "wall_time_s": self.wall_time_s,
            "real_time_factor": self.real_time_factor,
            "vehicles": [v.__dict__ | {"final_position_ned_m": list(v.final_position_ned_m)} for v in self.vehicles],
            "faults": self.faults,
            "incomplete_files": self.incomplete,
        }


def write_summary(out: Path, result: RunResult, extra: dict[str, Any]) -> None:
    """The final ``summary.json`` (atomically; it replaces the "running" checkpoints; in place when the disk is
    full). When it cannot be written at all, ``result`` says so (the file still says "running": read back, the
    run reads as killed)."""
    try:
        write_final_json(out / "summary.json", result.to_json() | extra | {"finished": True})
    except RecordingError as exc:
        result.status = RunStatus.FAILED
        if str(exc.path) not in result.incomplete:
            result.message = f"{result.message}; {exc}" if result.message else str(exc)
            result.incomplete.append(str(exc.path))
