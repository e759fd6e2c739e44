"""The tree of channels from the command line (issue 13): the root's side of ``harness run --accept``.

The root (``harness run --vehicles N --remote-vehicles M --accept tcp://0.0.0.0:PORT``) simulates the
physics of all N + M vehicles and flies vehicles 0…N-1 itself; vehicles N…N+M-1 are flown by the autopilots
of child channels that join over the network (``harness join``, :mod:`harness.run.join`), which bring
their own missions. So the summary, ``world.mcap`` / ``world.rrd`` and the plots of the run have every
vehicle of the tree (the ground truth is the root's), and each child's missions' exit codes reach the root
in its ANNOUNCE. Listening off loopback needs the shared secret, which is read from a file
(``--secret-file``) or the environment (``HARNESS_CHANNEL_SECRET``), never from the command line, and is
handed to child processes in their environment.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from harness.core.errors import ScenarioError, SimulationError
from harness.core.files import read_text

SECRET_ENV = "HARNESS_CHANNEL_SECRET"


def read_secret(secret_file: str | None) -> bytes | None:
    """The channel secret: the first line of ``secret_file``, else ``$HARNESS_CHANNEL_SECRET``, else None."""
    if secret_file:
        text = read_text(Path(secret_file), "--secret-file").strip()
        if not text:
            raise ScenarioError(f"--secret-file {secret_file}: the file is empty")
        return text.splitlines()[0].encode()
    env = os.environ.get(SECRET_ENV, "")
    return env.encode() if env else None


def secret_env(env: dict[str, str], secret: bytes | None) -> dict[str, str]:
    """``env`` with the secret for child processes (in the environment: never visible in ``ps``)."""
    return dict(env, **{SECRET_ENV: secret.decode()}) if secret else env


def wait_for_remote(
    channel: Any,
    vehicles: Sequence[int],
    timeout_s: float,
    progress: Callable[[str], None] | None,
    check: Callable[[], None] | None = None,
) -> None:
    """Pump the root channel until child channels hold every remote vehicle (before the first tick).
    ``check``: the children are placed by an engine, which raises when one of them failed."""
    want = set(vehicles)
    if not want:
        return
    if check is None and progress is not None:
        progress(
            f"waiting up to {timeout_s:g} s for vehicles {min(want)}-{max(want)} to join: "
            f"harness join {channel.address} --first-vehicle {min(want)} --vehicles {len(want)} --mission …"
        )

    def joined(_subs: object) -> bool:
        if check is not None:
            check()
        return want <= channel.held_vehicles()

    if not channel.wait_for(joined, timeout_s):
        missing = sorted(want - channel.held_vehicles())
        raise SimulationError(f"no child channel joined for vehicles {missing} within {timeout_s:g} s")


def missions_done(channel: Any, local_missions: int, first_remote: int) -> bool:
    """Every mission of the tree has ended: the root's own (vehicles below ``first_remote``, and a swarm
    mission) and those its children announced. False while no mission ever ran."""
    exits = channel.mission_exits
    local = sum(1 for e in exits if e.vehicle < first_remote)
    return len(exits) > 0 and local >= local_missions and channel.missions_below() == 0


def fill_remote(summaries: Sequence[Any], exits: Sequence[Any], first_remote: int) -> None:
    """Remote vehicles' missions as their children announced them (name and exit code)."""
    by_vehicle = {e.vehicle: e for e in exits}
    for s in summaries[first_remote:]:
        e = by_vehicle.get(s.id)
        if e is not None:
            s.mission, s.mission_exit_code = e.peer, e.exit_code


AUTO = 0
"""``--workers auto`` (the default): :func:`auto_workers` decides from the vehicle count and the cores."""
MIN_VEHICLES_PER_WORKER = 2
"""``auto`` gives a process a share only when it has at least this many vehicles. Two workers pay already
at 2 vehicles on an idle 2-core machine (``docs/tree.md``), but a host's vehicles have no home, mission or
geofence in the 3D view yet, so runs of 1–3 vehicles (the demo, most tests) stay in one process."""


def auto_workers(vehicles: int, cores: int | None = None) -> int:
    """One process per core this process may use, each with at least ``MIN_VEHICLES_PER_WORKER`` vehicles."""
    cores = len(os.sched_getaffinity(0)) if cores is None else cores
    return max(1, min(cores, vehicles // MIN_VEHICLES_PER_WORKER))


ROOT_OVERHEAD = 0.2
"""What the root process spends on each vehicle of the run besides stepping its own share (the channel's
phase ticks to missions and hosts, the ledger, the recordings), as a fraction of what stepping one vehicle
costs: measured on 10 vehicles in two processes (``docs/tree.md``). :func:`worker_groups` gives the root a
smaller share by that much, so that no process waits for the other."""


def worker_groups(vehicles: int, workers: int, root_overhead: float = 0.0) -> list[range]:
    """Vehicles 0…n-1 in ``workers`` contiguous shares (``AUTO``: :func:`auto_workers`), none empty. With
    ``root_overhead`` (the first share is the root's own, see :data:`ROOT_OVERHEAD`) the first share is
    smaller so that every process has the same work; the other shares are as equal as they go."""
    if workers == AUTO:
        workers = auto_workers(vehicles)
    workers = max(1, min(workers, vehicles))
    sizes = []
    if root_overhead > 0 and workers > 1:
        first = vehicles * (1.0 - (workers - 1) * root_overhead) / workers
        sizes.append(max(1, min(vehicles - (workers - 1), round(first))))
    base, extra = divmod(vehicles - sum(sizes), workers - len(sizes))
    sizes += [base + (1 if k < extra else 0) for k in range(workers - len(sizes))]
    out, start = [], 0
    for size in sizes:
        out.append(range(start, start + size))
        start += size
    return out


def parse_workers(text: str) -> int:
    """``--workers N|auto``: N, or ``AUTO`` (decided per run by :func:`auto_workers`)."""
    if text == "auto":
        return AUTO
    try:
        n = int(text)
    except ValueError:
        raise ScenarioError(f"--workers must be a number >= 1 or 'auto', got {text!r}") from None
    if n < 1:
        raise ScenarioError(f"--workers must be >= 1 or 'auto', got {n}")
    return n
