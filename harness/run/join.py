"""``harness join ADDRESS``: fly some vehicles of a run from another machine, as a child channel of its root.

Processes on the joining machine::

    harness join (this process)    a child channel (loopback) connected to the root channel at ADDRESS
      ├─ mission i (per vehicle)   harness mission SCRIPT on the sim clock, type 0 of the child channel
      └─ autopilot host            the vehicles' autopilots and MAVLink servers (python -m harness.autopilot.sitl)

The root (``harness run --remote-vehicles M --accept ADDRESS``) simulates the physics of every vehicle and
records the ground truth; BEGIN-TICK-AC of vehicles ``first … first + M - 1`` flow down to this child, the
autopilots here answer, and the root's phases run the missions here as well (the paper's tree of channels,
section III-C). Missions start before the autopilots, so they have joined (and the root knows them) before
the root's first tick. This command ends when the root ends the run (or on Ctrl-C); it exits 0 only when
every mission here exited 0.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import socket
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from harness.autopilot.firmware import Firmware
from harness.autopilot.process_config import AutopilotProcessConfig
from harness.channel import Channel, ChannelConfig
from harness.core.clock import NS_PER_S, WALL, Clock
from harness.core.endpoints import SYSIDS_PER_LINK, sysid
from harness.core.errors import ScenarioError, SimulationError, stop_reason
from harness.core.files import script_file
from harness.run import tree
from harness.run.children import Children
from harness.run.ports import PX4_API_BASE, allocate
from harness.run.swarm import mission_argv
from harness.scenario.plan import MissionPlan

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class JoinPlan:
    parent: str
    first_vehicle: int
    vehicles: int
    out: Path
    missions: tuple[MissionPlan | None, ...] = ()
    """Per vehicle of this machine (index 0 = ``first_vehicle``)."""
    secret: bytes | None = None
    name: str = ""
    firmware: Firmware = Firmware.PX4
    """The personality of every vehicle flown here."""
    stall_timeout_s: float = 30.0
    connect_timeout_s: float = 60.0
    progress: Callable[[str], None] | None = None
    physics: str | None = None
    """The run's ``physics.json`` here: the autopilot host steps these vehicles' physics too (else the root does)."""
    processes: int = 1
    """Autopilot processes here (the cores to use); more when one would show over 244 vehicles to its ground
    station (:data:`SYSIDS_PER_LINK`)."""

    @property
    def indices(self) -> range:
        return range(self.first_vehicle, self.first_vehicle + self.vehicles)


@dataclass(frozen=True)
class JoinResult:
    exits: dict[int, int | None]
    """Exit code of each vehicle's mission here (None: it never reported one)."""
    message: str
    timing: dict[str, float] = field(default_factory=dict)
    """The child channel's ticks and the wall time they took (``ticks``, ``tick_wall_s``, ``ms_per_tick``)."""
    gcs_ports: list[tuple[int, int, int]] = field(default_factory=list)
    """(ground-station udp port, first vehicle, last vehicle) of each autopilot process here."""

    @property
    def exit_code(self) -> int:
        if self.message:
            return 1
        return 0 if all(code == 0 for code in self.exits.values()) else 1


def plan_from_args(a: argparse.Namespace, rest: list[str], progress: Callable[[str], None]) -> JoinPlan:
    """The plan of ``harness join`` from its command line (``rest``: the missions' arguments)."""
    missions = [MissionPlan(Path(m), tuple(rest)) for m in a.mission]
    for m in missions:
        script_file(m.script, "--mission")
    if len(missions) == 1:
        missions = missions * a.vehicles
    return JoinPlan(
        parent=a.address,
        first_vehicle=a.first_vehicle,
        vehicles=a.vehicles,
        out=Path(a.out) if a.out else Path("runs") / time.strftime("join-%Y%m%d-%H%M%S"),
        missions=tuple(missions),
        secret=tree.read_secret(a.secret_file),
        name=a.name or "",
        firmware=Firmware.parse(a.firmware, "--firmware"),
        progress=progress,
    )


def default_name() -> str:
    return f"join:{socket.gethostname()}:{os.getpid()}"


def run_join(plan: JoinPlan, clock: Clock = WALL) -> JoinResult:
    """Join the run at ``plan.parent`` and fly its vehicles until the root ends the run (``clock``: the wall
    clock of its retries and waits)."""
    if plan.vehicles < 1 or plan.first_vehicle < 0:
        raise ScenarioError(
            f"harness join: need --first-vehicle >= 0 and --vehicles >= 1, got {plan.first_vehicle}, {plan.vehicles}"
        )
    plan.out.mkdir(parents=True, exist_ok=True)
    channel = _connect(plan, clock)
    message = ""
    wall_s = 0.0
    shown: list[tuple[int, int, int]] = []
    last = plan.indices[-1]
    try:
        with contextlib.ExitStack() as stack:
            ports = stack.enter_context(allocate(last + 1, PX4_API_BASE))
            groups = autopilot_groups(plan)  # each process its own ground-station port, for at most 244 vehicles
            gcs = [ports.gcs] + [stack.enter_context(allocate(0, PX4_API_BASE)).gcs for _ in groups[1:]]
            sup = stack.enter_context(Children(plan.out, clock=clock))
            try:
                env = tree.secret_env(
                    dict(os.environ, HARNESS_CHANNEL=channel.address, HARNESS_RUN_DIR=str(plan.out)), plan.secret
                )
                missions = _start_missions(plan, sup, channel.address, env, ports.api_base)
                _wait(
                    lambda: len(channel.subscribers()) >= missions,
                    60.0,
                    f"only some of the {missions} missions started (see {plan.out}/*.stderr)",
                    clock,
                )
                for k, (group, port) in enumerate(zip(groups, gcs, strict=True)):
                    name = f"autopilot-{k}" if k else "autopilot"
                    sup.start(name, _autopilot_argv(plan, name, group, channel.address, ports.api_base, port), env=env)
                    shown.append((port, group.start, group.stop - 1))
                if plan.progress is not None:
                    plan.progress(
                        f"joined {plan.parent} as {channel.config.name}: vehicles {plan.first_vehicle}-{last}; "
                        + ", ".join(f"ground-station udp port {g} shows vehicles {a}-{b}" for g, a, b in shown)
                    )
                started = clock.now_ns()
                message = _supervise(channel, sup)
                wall_s = (clock.now_ns() - started) / NS_PER_S
            except KeyboardInterrupt as exc:
                message = stop_reason(exc)
            except SimulationError as exc:
                message = str(exc)
            finally:
                channel.stop()
    finally:  # the ports or the supervisor failed before the block: the joined channel stops all the same
        channel.stop()
    exits = {e.vehicle: e.exit_code for e in channel.mission_exits}
    ticks = channel.ticks_done
    timing = {"ticks": ticks, "tick_wall_s": wall_s, "ms_per_tick": 1e3 * wall_s / ticks if ticks else 0.0}
    return JoinResult(
        {i: exits.get(i) for i, m in zip(plan.indices, plan.missions, strict=False) if m}, message, timing, shown
    )


def _connect(plan: JoinPlan, clock: Clock) -> Channel:
    """The child channel, connected to the root: retried while nothing listens there yet (the root may be
    started after this command), for ``connect_timeout_s``; a refusal (wrong secret, taken vehicles) is final."""
    end = clock.now_ns() + int(plan.connect_timeout_s * NS_PER_S)
    while True:
        channel = Channel(
            ChannelConfig(
                name=plan.name or default_name(),
                parent=plan.parent,
                secret=plan.secret,
                stall_timeout_s=plan.stall_timeout_s,
            )
        )
        try:
            return channel.start()
        except Exception as exc:  # refused, wrong secret, no such host: one line
            channel.close("could not join")
            if "cannot reach the channel" not in str(exc) or clock.now_ns() > end:
                raise SimulationError(f"harness join: cannot join the run at {plan.parent}: {exc}") from None
        clock.sleep_ns(NS_PER_S // 2)


def _start_missions(plan: JoinPlan, sup: Children, address: str, env: dict[str, str], api_base: int) -> int:
    count = 0
    for i, m in zip(plan.indices, plan.missions, strict=False):
        if m is None:
            continue
        fw = plan.firmware
        menv = dict(env, HARNESS_VEHICLE=str(i), HARNESS_SYSID=str(sysid(i)), HARNESS_MAVLINK_PORT=str(api_base + i))
        menv["HARNESS_FIRMWARE"] = fw.value
        if fw is Firmware.ARDUPILOT:
            menv["HARNESS_MAVLINK_TCP_PORT"] = str(api_base + i)
        sup.start(f"mission-{i}", mission_argv(sys.executable, address, i, m.script, m.args), env=menv)
        count += 1
    return count


def autopilot_groups(plan: JoinPlan) -> list[range]:
    """The vehicles of each autopilot process here: ``plan.processes`` contiguous shares, and as many more as it
    takes for none to hold more than :data:`SYSIDS_PER_LINK` (system ids repeat beyond: a ground station on
    one port must not see two vehicles with one id)."""
    count = max(plan.processes, -(-plan.vehicles // SYSIDS_PER_LINK))
    return [
        range(plan.first_vehicle + g.start, plan.first_vehicle + g.stop)
        for g in tree.worker_groups(plan.vehicles, count)
    ]


def _autopilot_argv(plan: JoinPlan, name: str, group: range, address: str, api_base: int, gcs: int) -> list[str]:
    """An autopilot process of this machine's vehicles ``group``, configured by ``<out>/<name>.json``."""
    config = AutopilotProcessConfig(
        address=address,
        vehicles=tuple(group),
        api_port_base=0,
        api_local_port_base=api_base,
        gcs_port=gcs,
        run_dir=str(plan.out),
        firmware=(plan.firmware,),
        tcp_port_base=api_base,
        tcp_sim_clients=True,
        physics=plan.physics,
    )
    config_file = plan.out / f"{name}.json"
    config_file.write_bytes(config.to_json())
    return [sys.executable, "-m", "harness.autopilot.sitl", "--config", str(config_file)]


def _wait(predicate: Callable[[], bool], timeout_s: float, why: str, clock: Clock) -> None:
    end = clock.now_ns() + int(timeout_s * NS_PER_S)
    while not predicate():
        if clock.now_ns() > end:
            raise SimulationError(f"harness join: {why}")
        clock.sleep_ns(20_000_000)


def _supervise(channel: Channel, sup: Children) -> str:
    """Until the root ends the run: '' when it did, else why this machine's part failed."""
    while not channel.wait(0.2):
        for name, code in sup.poll_exits():
            if name.startswith("autopilot"):
                return f"the {name} process exited with {code} (see {name}.stderr)"
    return channel.failure or ""
