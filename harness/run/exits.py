"""How each mission of a run ended, as it ended: the exit status of its process where the channel saw less.

A mission that ends normally says goodbye to the channel with its exit code (BYE). One that ends without a
word — ``os._exit(0)``, ``kill -9``, the OOM killer — is seen by the channel only as a connection that closed,
and recorded as ``-1`` ("dropped: disconnected"). Its process knows better: :func:`settle` replaces such a
record with the process's own exit status (``0``; ``-9``, "killed by SIGKILL"), once the process has ended.
"""

from __future__ import annotations

import signal
import subprocess
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from harness.run.swarm import SWARM_VEHICLE
from harness.scenario.plan import LaunchPlan

DISCONNECTED = ("dropped: disconnected", "dropped: connection broke")
"""How the channel records a mission whose connection closed without a goodbye."""


def status_text(code: int) -> str:
    """``-9`` → ``killed by SIGKILL``; an exit code → ``exited with N``."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exited with {code}"


def mission_process(plan: LaunchPlan) -> Callable[[int], str | None]:
    """The name a run gives the process (in ``Children``) of a vehicle's mission, or of the swarm mission."""

    def name(vehicle: int) -> str | None:
        if vehicle == SWARM_VEHICLE:
            return "swarm-mission" if plan.swarm_mission is not None else None
        return f"mission-{vehicle}" if 0 <= vehicle < plan.vehicles else None

    return name


def settle(
    exits: Sequence[Any], procs: Mapping[str, Any], process_of: Callable[[int], str | None], wait_s: float
) -> list[str]:
    """Give each mission the channel lost without a goodbye its process's exit status (``exits``: the
    channel's ``MissionExit`` records, changed in place; ``process_of(vehicle)``: the name of the mission's
    process in ``procs``). A process that has not ended within ``wait_s`` (its connection broke, it runs on)
    keeps the channel's record. Returns the names of the peers settled."""
    settled = []
    for e in exits:
        if e.exit_code != -1 or not e.reason.startswith(DISCONNECTED):
            continue
        name = process_of(e.vehicle)
        proc = procs.get(name) if name is not None else None
        if proc is None:
            continue
        try:
            code = proc.wait(wait_s)
        except subprocess.TimeoutExpired:
            continue
        e.exit_code = code
        e.reason = f"{status_text(code)}, without a goodbye to the channel" if code >= 0 else status_text(code)
        settled.append(e.peer)
    return settled
