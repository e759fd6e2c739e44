"""The launcher behind ``harness run``: physics + root channel in this process, everything else supervised.

Processes of a run::

    harness run (this process)     root channel + recorder + progress; physics and autopilots of the first share
      ├─ autopilot host (each)     physics, autopilots and MAVLink servers of one more share (--workers,
      │                            python -m harness.autopilot.sitl --config RUN/autopilot.json)
      ├─ network (optional)        the type-1 network subscriber
      └─ mission i (per vehicle)   harness mission SCRIPT on the sim clock (type 0)

The loop is the paper's tick, driven from here: physics frames → ``channel.step`` (autopilots answer,
missions run phase 0, the network phase 1) → motor commands → physics. The run ends when every mission
has exited, the duration is reached, a fault fails the run, or on Ctrl-C; every child is then stopped.
"""

from __future__ import annotations

import contextlib
import gc
import logging
import os
import secrets
import socket
import sys
import tempfile
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec

from harness.autopilot.camera import Capture
from harness.autopilot.events import decode_events
from harness.autopilot.firmware import Firmware
from harness.autopilot.process_config import AutopilotProcessConfig
from harness.channel import Channel, ChannelConfig
from harness.core import jit
from harness.core.clock import NS_PER_S, WALL, Clock
from harness.core.errors import ScenarioError, SimulationError, stop_reason
from harness.core.files import RecordingError, first_per_file, lost_message, writable_dir
from harness.fdm.physics import Physics, PhysicsConfig, WindConfig, WorldOrigin
from harness.fdm.sensors import SensorConfig
from harness.net.process_config import NetworkProcessConfig
from harness.record.sample import VehicleSample, WorldEvent
from harness.record.sink import WorldSink, WorldTee, open_world
from harness.record.status import Checkpoint
from harness.run import swarm, tree
from harness.run.children import Children
from harness.run.exits import mission_process, settle
from harness.run.ledger import Ledger, Row
from harness.run.link import NativeLink
from harness.run.pacing import Pacer
from harness.run.ports import allocate
from harness.run.result import RunResult, RunStatus, VehicleSummary, write_summary
from harness.scenario.limits import check_plan
from harness.scenario.plan import AutopilotPlacement, LaunchPlan, MissionPlan, NetworkKind
from harness.wire import protocol as p

if TYPE_CHECKING:  # the flight stack is imported when the in-process autopilots are built, after the children
    # have started (``_local_autopilots``): at module level it would put its import (numba's kernels: 1.4 s
    # by `python -X importtime` on the loaded two-core machine) before them
    from harness.autopilot.autopilot import Autopilot
    from harness.autopilot.sitl import AttachedMavlink

PHYSICS_FILE = "physics.json"
"""The run's physics configuration in its directory, from which each autopilot host builds its share."""

log = logging.getLogger(__name__)


def _python() -> str:
    return sys.executable


@dataclass
class _Run:
    """What one run holds (:meth:`Launcher._open`), every resource of it on the run's ``ExitStack``."""

    channel: Channel
    world: WorldTee
    sup: Children
    local: contextlib.ExitStack
    """The in-process autopilots' MAVLink side: closed after the channel, before the recorders."""
    checkpoint: Checkpoint
    physics_cfg: PhysicsConfig
    in_hosts: frozenset[int]
    """Vehicles whose physics an autopilot host steps (configured by ``physics.json``)."""
    summaries: list[VehicleSummary]
    settled: list[str]
    """Missions whose process said how they ended (filled just before the children are stopped)."""
    wall0: int
    phys: Physics | None = None
    """This process's share of the physics: built while the children start (they import meanwhile)."""
    aps: dict[int, Autopilot] = field(default_factory=dict)
    """Autopilots inside this process (``autopilots = "in-process"``), by vehicle."""
    attached: list[AttachedMavlink] = field(default_factory=list)
    """Their MAVLink sides (with their tlog and ULog writers)."""
    status: RunStatus = RunStatus.OK
    message: str = ""
    lost: list[RecordingError] = field(default_factory=list)

    @property
    def t_ns(self) -> int:
        return self.phys.t_ns if self.phys is not None else 0

    def log_errors(self) -> list[RecordingError]:
        """The vehicles' logs in this process (tlogs, ULogs) that could not be written."""
        return [RecordingError.of(path, exc) for handle in self.attached for path, exc in handle.write_errors()]


class Launcher:
    """Runs one plan. ``run()`` returns the result; the summary is written in any case. ``clock``: the wall
    clock of pacing, progress, the MAVLink side and the run's date (the sim clock is the physics)."""

    def __init__(self, plan: LaunchPlan, clock: Clock = WALL) -> None:
        check_plan(plan)  # every setting within its bounds before anything starts (limits.py)
        self.plan = plan
        self.clock = clock
        writable_dir(plan.out)  # a read-only or full file system, a file in the way: one line, nothing started
        self.epoch_ns = clock.unix_ns() // NS_PER_S * NS_PER_S
        self.paused = threading.Event()
        """While set, the clock stands still (no ticks); MAVLink keeps answering on the wall clock."""
        self._pause_timer: threading.Timer | None = None
        self._pacing: dict[str, float] | None = None
        """``--speed``'s account of a run that ended normally (``_pacing``)."""
        self.api_port_base, self.gcs_port = plan.api_port_base, plan.gcs_port or 0
        self.tcp_port_base = plan.tcp_port_base or plan.api_port_base
        self._tcp_sim_clients = plan.api_remote_base == 0
        """A batch run (nothing sent unasked to hand-run tools): the ArduPilot vehicles' TCP clients are its
        missions, on sim time; `harness sitl` serves hand-run tools on the wall clock there."""

    def run(self) -> RunResult:
        """The run context (every resource on one ExitStack, released in reverse order however the run ends),
        start-up, the tick loop, then the result and ``summary.json`` once every process is gone."""
        run: _Run | None = None
        try:
            with contextlib.ExitStack() as stack:
                run = self._open(stack)
                self._fly(run)
        except Exception as exc:
            if run is None:  # nothing started (a port taken, a bad plan): the caller says so in one line
                raise
            # a resource that failed to close: the stack released every other one all the same
            log.exception("closing the run failed")
            if run.status is RunStatus.OK:
                run.status, run.message = RunStatus.FAILED, f"internal error while closing the run: {exc!r}"
        return self._result(run)

    def _fly(self, run: _Run) -> None:
        """Start-up and the tick loop; how they ended goes into ``run.status`` (the run context stays open)."""
        try:
            self._start(run)
            # What start-up built (modules, JSBSim, autopilots, Rerun) lives to the end of the run: out of the
            # cycle collector's sight while the loop runs, a full collection walks only what the loop made
            # (at 100 vehicles one took 60-75 ms of CPU, 11 times in 30 s of sim). No result changes.
            gc.freeze()
            try:
                self._loop(run)
            finally:
                gc.unfreeze()
        except KeyboardInterrupt as exc:
            run.status, run.message = RunStatus.INTERRUPTED, stop_reason(exc)
            run.world.interrupted()
        except SimulationError as exc:
            run.status, run.message = RunStatus.FAILED, str(exc)
            if isinstance(exc, RecordingError):
                run.lost.append(exc)
        except Exception as exc:  # a bug must still stop every process and write the summary
            log.exception("the run failed")
            run.status, run.message = RunStatus.FAILED, f"internal error: {exc!r}"

    def _open(self, stack: contextlib.ExitStack) -> _Run:
        """The run's resources, each on ``stack`` as soon as it exists, so that they are released in this
        order: the channel (every peer told), the in-process autopilots' MAVLink side (first: its thread would
        compete with the recorders' closing), the recorders, the missions' own ends (:func:`settle`), every
        child process, the reserved ports (the block stays this run's until every process has stopped)."""
        plan = self.plan
        n = plan.vehicles + plan.remote_vehicles
        physics_cfg = PhysicsConfig(
            n_vehicles=n,
            seed=plan.seed,
            substep_hz=plan.physics_hz,
            tick_hz=plan.tick_hz,
            origin=WorldOrigin(*plan.world_origin),
            heading_deg=plan.heading_deg or 0.0,
            wind=WindConfig(steady_ned_m_s=plan.wind_ned_m_s, turbulence=plan.turbulence),
            spawn_ned_m=plan.spawn_ned_m,
            sensors=SensorConfig.for_gps(plan.gps, noise=plan.sensor_noise),
        )
        # each autopilot host steps its vehicles' physics too (configured by this file); this process the rest
        in_hosts = frozenset(v for group in self._autopilot_groups() for v in group)
        if in_hosts:
            try:
                (plan.out / PHYSICS_FILE).write_bytes(physics_cfg.to_json())
            except OSError as exc:
                raise RecordingError.of(plan.out / PHYSICS_FILE, exc) from None
        wall0 = self.clock.now_ns()
        ports = stack.enter_context(allocate(plan.vehicles, plan.api_port_base, plan.gcs_port))
        self.api_port_base, self.gcs_port = ports.api_base, ports.gcs
        self.tcp_port_base = plan.tcp_port_base if plan.tcp_port_base is not None else ports.api_base
        sup = stack.enter_context(Children(plan.out, clock=self.clock, fork_preload=swarm.MISSION_PRELOAD))
        # the channel's close goes on the stack after the recorders' (it is released first); until attach_physics()
        # below it holds only its wake-up socket pair, nothing listens
        channel = Channel(
            ChannelConfig(
                tick_hz=plan.tick_hz,
                phase_every=plan.phase_every,
                stall_timeout_s=plan.stall_timeout_s,
                epoch_ns=self.epoch_ns,
                name="root",
                address=_root_address(plan),
                secret=plan.secret,
            )
        )
        settled: list[str] = []
        # a mission the channel saw only disconnect (os._exit, kill -9): its process says how it ended
        stack.callback(lambda: settled.extend(settle(channel.mission_exits, sup.procs, mission_process(plan), 2.0)))
        world = open_world(plan.out, self.epoch_ns, n, plan.world_origin, serve_port=plan.view_port)
        stack.callback(world.close)
        local = stack.enter_context(contextlib.ExitStack())
        stack.callback(channel.close, "end of run")
        channel.attach_physics()
        summaries = [VehicleSummary(i, _mission_name(plan, i)) for i in range(n)]
        extra, clock = self._summary_extra, self.clock
        checkpoint = Checkpoint(  # summary.json while the run runs; ``run`` is bound below, before the first write
            plan.out,
            lambda: (
                RunResult(
                    RunStatus.RUNNING, run.t_ns / NS_PER_S, (clock.now_ns() - wall0) / NS_PER_S, summaries, []
                ).to_json()
                | extra()
            ),
            lambda: self._flush_recordings(run),
            clock=clock,
        )
        run = _Run(channel, world, sup, local, checkpoint, physics_cfg, in_hosts, summaries, settled, wall0)
        checkpoint.write()
        return run

    def _start(self, run: _Run) -> None:
        """Children first (each takes a while to import and join), this process's share of the physics and
        its autopilots meanwhile; then every process and remote vehicle in the channel."""
        plan = self.plan
        n = plan.vehicles + plan.remote_vehicles
        channel = run.channel
        self._tell_ports(run.world)
        self._start_children(run.sup, channel.address, lambda: channel.pump(0.001))
        own = [v for v in range(n) if v not in run.in_hosts]
        jit.prefer(len(own) >= 2)  # numba's start-up pays back from two vehicles (harness.core.jit)
        run.phys = Physics(run.physics_cfg, own)
        if plan.autopilots == AutopilotPlacement.IN_PROCESS:
            run.aps, run.attached = self._local_autopilots(run.local)
            run.world.attach_autopilots(run.aps)
        hosts = 2 * len(self._autopilot_groups())  # each also has its clock (a type-1 connection)
        expected = hosts + (1 if plan.network != NetworkKind.NONE else 0) + _mission_count(plan)
        start_s = max(60.0, 2.0 * expected)  # a hundred processes importing MAVSDK on two busy cores
        if not channel.wait_for(lambda subs: _all_joined(subs, expected, run.sup), timeout_s=start_s):
            raise SimulationError(
                f"only {len(channel.subscribers())} of {expected} processes joined the channel within {start_s:g} s "
                f"(see the *.stderr files in {plan.out})"
            )
        tree.wait_for_remote(channel, range(plan.vehicles, n), plan.join_timeout_s, plan.progress)

    def _tell_ports(self, world: WorldTee) -> None:
        """The progress lines of the MAVLink ports (and the live view's address) before anything starts."""
        plan = self.plan
        if plan.progress is not None:
            plan.progress(
                f"MAVLink: ground station on udp port {self.gcs_port}; vehicle i listens on udp port "
                f"{self.api_port_base}+i (each mission's udpin://0.0.0.0:14540 is redirected there)"
            )
            if plan.gcs_port and self.gcs_port != plan.gcs_port:
                plan.progress(f"MAVLink: udp port {plan.gcs_port} is another harness run's ground station port")
            ardupilot = [i for i in range(plan.vehicles) if plan.firmware_of(i) is Firmware.ARDUPILOT]
            if ardupilot:
                step = plan.tcp_port_step
                plan.progress(
                    f"MAVLink: ArduPilot vehicles {ardupilot} listen on tcp port {self.tcp_port_base}"
                    + (f"+{step}*i" if step != 1 else "+i")
                    + (f", and also send to udp {list(plan.gcs_extra_ports)}" if plan.gcs_extra_ports else "")
                )
        if plan.on_view is not None and world.view is not None and world.view.grpc_url:
            plan.on_view(world.view.grpc_url)

    def _result(self, run: _Run) -> RunResult:
        """The run's result, written to ``summary.json``: its status, then each mission's end, the faults the
        channel saw (but not of missions whose process said how they ended), a crash, recordings lost."""
        plan = self.plan
        channel, summaries = run.channel, run.summaries
        status, message = run.status, run.message
        lost = first_per_file(run.lost + run.world.errors + run.log_errors())  # recordings that could not be completed
        if lost:
            status, message = RunStatus.FAILED, lost_message(lost)
        wall_s = (self.clock.now_ns() - run.wall0) / NS_PER_S
        t_ns = run.t_ns
        exits = {e.vehicle: e for e in channel.mission_exits}
        swarm_end = swarm.swarm_exit(channel.mission_exits)
        tree.fill_remote(summaries, channel.mission_exits, plan.vehicles)
        for s in summaries:
            if s.mission is not None:
                e = swarm_end if s.id < plan.vehicles and not _own_mission(plan, s.id) else exits.get(s.id)
                s.mission_exit_code = e.exit_code if e is not None else None
                s.mission_exit_reason = e.reason if e is not None else ""
                if status == RunStatus.OK and (e is None or e.exit_code != 0):
                    status = RunStatus.FAILED
                    message = message or (
                        f"the mission of vehicle {s.id} was still running when the run ended at "
                        f"{t_ns / NS_PER_S:.1f} s of sim time"
                        if e is None
                        else f"the mission of vehicle {s.id} exited with {e.exit_code} ({e.reason})"
                    )
        faults = [f.__dict__ for f in channel.faults if f.peer not in run.settled]
        if any(s.crashed for s in summaries) and status == RunStatus.OK:
            status, message = RunStatus.FAILED, "a vehicle crashed"
        result = RunResult(status, t_ns / NS_PER_S, wall_s, summaries, faults, message, [str(e.path) for e in lost])
        write_summary(plan.out, result, self._summary_extra())
        return result

    def _flush_recordings(self, run: _Run) -> None:
        """Every second: ``world.mcap``'s chunk in progress to disk, and a log that could not be written stops
        the run (:class:`RecordingError`, naming the file)."""
        run.world.flush_mcap()
        lost = run.log_errors()
        if lost:
            raise lost[0]

    def _summary_extra(self) -> dict[str, Any]:
        plan = self.plan
        return {
            "seed": plan.seed,
            "api_port_base": self.api_port_base,
            "gcs_port": self.gcs_port,
            "tick_hz": plan.tick_hz,
            "physics_hz": plan.physics_hz,
            "phase_every": plan.phase_every,
        } | ({"pacing": self._pacing} if self._pacing is not None else {})

    def toggle_pause(self) -> None:
        """Pause or resume the clock (``harness run`` does this on SIGUSR1)."""
        if self.paused.is_set():
            self.paused.clear()
        else:
            self.paused.set()

    def _local_autopilots(self, local: contextlib.ExitStack) -> tuple[dict[int, Autopilot], list[AttachedMavlink]]:
        """Autopilots (and their MAVLink servers, tlogs, stored parameters) inside this process, by vehicle, and
        their MAVLink sides; what closes those is on ``local`` from the start (a vehicle that cannot bind its port
        leaves the others' closed)."""
        from harness.autopilot.autopilot import Autopilot, AutopilotConfig
        from harness.autopilot.mavlink.hub import MavlinkHub
        from harness.autopilot.mavlink.personality import core_param_defaults
        from harness.autopilot.mavlink.runlocal import run_signing
        from harness.autopilot.mavlink.transport import PortsConfig
        from harness.autopilot.sitl import attach_mavlink, close_mavlink, vehicle_ports

        plan = self.plan
        aps = {
            i: Autopilot(
                AutopilotConfig(
                    vehicle=i,
                    params={
                        **core_param_defaults(plan.firmware_of(i)),
                        "SIM_SPEEDUP": plan.speed or 0.0,
                        **(plan.params[i] if i < len(plan.params) else {}),
                    },
                ),
                wall_clock=self.clock,
            )
            for i in self._groups()[0]
        }
        # each vehicle binds its API port; missions connect out to it, and nothing goes to anyone else's port
        ports = PortsConfig(
            api_port_base=plan.api_remote_base, api_local_port_base=self.api_port_base, gcs_port=self.gcs_port
        )
        signing, trust = run_signing(plan.signing_key_file, os.getpid())  # unsigned: only this run's processes
        hub = MavlinkHub(name="mavlink", clock=self.clock)  # one wall-clock thread serves every vehicle
        attached: list[AttachedMavlink] = []
        local.callback(close_mavlink, hub, attached)
        try:
            for i, ap in aps.items():
                fw = plan.firmware_of(i)
                vp = vehicle_ports(
                    ports, fw, self.tcp_port_base, plan.tcp_port_step, plan.gcs_extra_ports, self._tcp_sim_clients
                )
                attached.append(attach_mavlink(ap, vp, plan.out, signing, hub, fw, trust))
        except ScenarioError as exc:  # a port taken by another simulator: one line, not a traceback
            raise SimulationError(str(exc)) from None
        hub.start()  # once every server is in: an add to a running hub waits for its thread
        return aps, attached  # stepped by the channel through NativeLink, with the frame objects themselves

    def _start_children(self, sup: Children, address: str, pump: Callable[[], None] = lambda: None) -> None:
        """Start the run's processes; ``pump`` between missions answers the handshakes of those already up
        (100 process starts take long enough on a busy machine for the first ones' handshakes to time out)."""
        plan = self.plan
        env = tree.secret_env(dict(os.environ, HARNESS_CHANNEL=address, HARNESS_RUN_DIR=str(plan.out)), plan.secret)
        pace = {"SIM_SPEEDUP": plan.speed or 0.0}  # the run's pace, as ArduPilot's SIM_SPEEDUP reads it
        overrides = {i: pace | (plan.params[i] if i < len(plan.params) else {}) for i in range(plan.vehicles)}
        for k, group in enumerate(self._autopilot_groups()):
            name = f"autopilot-{k}" if k else "autopilot"
            config = AutopilotProcessConfig(
                address=address,
                vehicles=tuple(group),
                api_port_base=plan.api_remote_base,
                api_local_port_base=self.api_port_base,
                gcs_port=self.gcs_port,
                run_dir=str(plan.out),
                params=overrides,
                signing_key_file=str(plan.signing_key_file.resolve()) if plan.signing_key_file is not None else None,
                trust_run=os.getpid() if plan.signing_key_file is not None else 0,
                firmware=tuple(plan.firmware_of(i) for i in range(plan.vehicles)),
                tcp_port_base=self.tcp_port_base,
                tcp_port_step=plan.tcp_port_step,
                gcs_extra_ports=tuple(plan.gcs_extra_ports),
                tcp_sim_clients=self._tcp_sim_clients,
                physics=str(plan.out / PHYSICS_FILE),
                name=name,
            )  # the key's file, never the key
            config_file = plan.out / f"{name}.json"
            config_file.write_bytes(config.to_json())
            sup.start(name, [_python(), "-m", "harness.autopilot.sitl", "--config", str(config_file)], env=env)
        if plan.network != NetworkKind.NONE:
            network = NetworkProcessConfig(
                address=address, model=plan.network, seed=plan.seed, params=plan.network_params, run_dir=str(plan.out)
            )
            config_file = plan.out / "network.json"
            config_file.write_bytes(network.to_json())
            sup.start("network", [_python(), "-m", "harness.net.subscriber", "--config", str(config_file)], env=env)
        forked = _mission_count(plan) > 1  # one fork server imports for them all (one: it would only add a hop)
        for i, m in enumerate(plan.missions[: plan.vehicles]):
            if m is None:
                continue
            menv = dict(
                env, HARNESS_VEHICLE=str(i), HARNESS_SYSID=str(i + 1), HARNESS_MAVLINK_PORT=str(self.api_port_base + i)
            )
            fw = plan.firmware_of(i)
            menv["HARNESS_FIRMWARE"] = fw.value
            if fw is Firmware.ARDUPILOT:  # SERIAL0: a script's tcp:127.0.0.1:5760 is sent here
                menv["HARNESS_MAVLINK_TCP_PORT"] = str(self._tcp_port(i))
            sup.start(
                f"mission-{i}", _mission_argv(address, i, m), env=menv, forked=forked, terminal=plan.mission_stdin
            )
            pump()
        if plan.swarm_mission is not None:
            team = swarm.swarm_vehicles(plan.vehicles, self.api_port_base, plan.firmware_of, self._tcp_port)
            m = plan.swarm_mission
            name = swarm.peer_name(m.script.name)
            argv = _mission_argv(address, swarm.SWARM_VEHICLE, m, name)
            sup.start("swarm-mission", argv, env=swarm.swarm_env(env, team), forked=forked, terminal=plan.mission_stdin)

    def _autopilot_groups(self) -> list[range]:
        """The vehicles of each autopilot process (the first share stays in this process when in-process)."""
        groups = self._groups()
        return groups[1:] if self.plan.autopilots == AutopilotPlacement.IN_PROCESS else groups

    def _groups(self) -> list[range]:
        """Every process's vehicles; in-process, the first share is this (the root) process's own, smaller
        by what the root does besides (:data:`tree.ROOT_OVERHEAD`)."""
        in_process = self.plan.autopilots == AutopilotPlacement.IN_PROCESS
        return tree.worker_groups(self.plan.vehicles, self.plan.workers, tree.ROOT_OVERHEAD if in_process else 0.0)

    def _tcp_port(self, vehicle: int) -> int:
        return self.tcp_port_base + self.plan.tcp_port_step * vehicle

    def _loop(self, run: _Run) -> None:
        """The ticks, until the duration is reached or every mission has ended (a failure raises)."""
        plan = self.plan
        phys, channel, world, summaries, sup, checkpoint = (
            run.phys,
            run.channel,
            run.world,
            run.summaries,
            run.sup,
            run.checkpoint,
        )
        assert phys is not None and checkpoint is not None
        n = plan.vehicles + plan.remote_vehicles
        record_every = max(1, round(plan.tick_hz / plan.record_hz))
        end_ns = None if plan.duration_s is None else round(plan.duration_s * NS_PER_S)
        missions = _mission_count(plan)
        frames = phys.frames()
        link = NativeLink(channel, run.aps, {h.server.vehicle: h.server.sent_to_missions for h in run.attached})
        paused_once = False
        wall0 = self.clock.now_ns()
        pacer = Pacer(plan.speed, wall0) if plan.speed is not None else None
        last_progress = wall0
        motors: list[tuple[float, ...]] = [(0.0, 0.0, 0.0, 0.0)] * n
        own = phys.owned
        elsewhere = {v: phys.cfg.spawn(v) for v in range(n) if v not in set(own)}
        """Vehicles whose physics runs in an autopilot host (asked at phase ticks), with their last position."""
        ledger = Ledger(n)
        while True:
            t_ns = phys.t_ns
            tick = phys.tick
            if (end_ns is not None and t_ns >= end_ns) or tree.missions_done(channel, missions, plan.vehicles):
                if pacer is not None:
                    self._pacing = _pacing(pacer, t_ns, wall0, self.clock.now_ns())
                return
            if plan.pause_at_s is not None and not paused_once and t_ns >= plan.pause_at_s * NS_PER_S:
                paused_once = True
                self.paused.set()
                self._pause_timer = threading.Timer(plan.pause_wall_s, self.paused.clear)
                self._pause_timer.daemon = True
                self._pause_timer.start()
            if self.paused.is_set():
                stopped = self.clock.now_ns()
                world.event(t_ns, WorldEvent.PAUSED, {})
                while self.paused.is_set():
                    self.clock.sleep_ns(20_000_000)
                stalled = self.clock.now_ns() - stopped
                wall0 += stalled
                if pacer is not None:
                    pacer.shift(stalled)  # pacing resumes from here, it does not rush to catch up
                world.event(t_ns, WorldEvent.RESUMED, {"paused_wall_s": stalled / NS_PER_S})
            if pacer is not None:  # a rate, not a schedule: after a stall the run goes on at the speed asked
                self.clock.sleep_ns(pacer.wait_ns(t_ns, self.clock.now_ns()))
            tick_start = self.clock.now_ns()
            phase = tick % plan.phase_every == 0
            etas = link.exchange(t_ns, tick, frames, elsewhere if phase else None)
            now = self.clock.now_ns()
            truth: list[p.TruthLike | None] = [None] * n  # the hosts' vehicles: once they report
            for f in frames:
                truth[f.vehicle] = f.truth
            row = Row(tick, t_ns, (now - wall0) / NS_PER_S, (now - tick_start) / 1e3, truth, [()] * n, [0] * n)
            ledger.open(row)
            for e in etas:
                if e.ticks:
                    reports = p.unpack_ticks(e.ticks)
                    ledger.reported(e.vehicle, tick, reports)
                    elsewhere[e.vehicle] = reports[-1].truth.pos_ned_m
                else:
                    motors[e.vehicle] = row.motors[e.vehicle] = e.motors
                    row.status[e.vehicle] = e.status
                if e.events:  # SIM_* changes (before the next physics step), pictures
                    pacer = self._vehicle_events(e.vehicle, e.events, phys, world, pacer)
            done = list(ledger.complete())
            if done:
                self.record_rows(done, record_every, summaries, world)
            if phase:
                ledger.check_through(tick)
            frames = phys.step([motors[v] for v in own])
            if tick % 50 == 0:  # every 0.2 s of sim time: a child's death is noticed, waitpid stays cheap
                for name, code in sup.poll_exits():
                    if name.startswith("autopilot") or name == "network":
                        raise SimulationError(f"the {name} process exited with {code} (see {name}.stderr)")
            checkpoint.maybe()
            if plan.progress is not None and self.clock.now_ns() - last_progress > 500_000_000:
                last_progress = self.clock.now_ns()
                plan.progress(self._progress_line(t_ns, last_progress - wall0, summaries, channel, missions))

    def _vehicle_events(
        self, vehicle: int, data: bytes, phys: Physics, world: WorldSink, pacer: Pacer | None
    ) -> Pacer | None:
        """A vehicle's events: changes of its simulated world applied (a host's vehicle: applied there) and
        recorded, a new ``SIM_SPEEDUP`` pacing the run from now on (0: as fast as possible); its pictures recorded.
        Returns the pacer."""
        for event in decode_events(data):
            if isinstance(event, Capture):
                world.capture(vehicle, event)
                continue
            phys.apply(vehicle, event)
            world.event(event.t_ns, WorldEvent.SIM, {"vehicle": vehicle, **msgspec.structs.asdict(event)})
            if event.speedup is not None:
                now = self.clock.now_ns()
                pacer = Pacer(event.speedup, now - int(event.t_ns / event.speedup)) if event.speedup > 0 else None
        return pacer

    @staticmethod
    def record_rows(rows: list[Row], record_every: int, summaries: list[VehicleSummary], world: WorldSink) -> None:
        """Ticks every vehicle's truth is known at, oldest first: recorded (every ``record_every``-th), and the
        summaries (the highest altitude and a crash at every tick; the rest as of the last one)."""
        for row in rows:
            t_ns = row.t_ns
            if row.tick % record_every == 0:
                for v, tr in enumerate(row.truth):
                    world.vehicle(
                        VehicleSample(
                            t_ns,
                            v,
                            tr.pos_ned_m,
                            tr.quat,
                            tr.vel_ned_m_s,
                            tr.lat_deg,
                            tr.lon_deg,
                            tr.alt_amsl_m,
                            row.motors[v],
                            tr.on_ground,
                            tr.crashed,
                            row.status[v],
                        )
                    )
                world.tick(t_ns, row.tick, row.wall_s, row.tick_us)
            for s, tr in zip(summaries, row.truth, strict=True):
                alt = -tr.pos_ned_m[2]
                if alt > s.max_altitude_m:
                    s.max_altitude_m = alt
                if tr.crashed and not s.crashed:
                    s.crashed = True
                    world.event(t_ns, WorldEvent.CRASH, {"vehicle": s.id})
        last = rows[-1]
        for s, tr, status in zip(summaries, last.truth, last.status, strict=True):
            s.armed = status & p.STATUS_ARMED != 0
            s.final_position_ned_m = tr.pos_ned_m
            s.landed = tr.on_ground

    @staticmethod
    def _progress_line(
        t_ns: int, wall_ns: int, summaries: list[VehicleSummary], channel: Channel, missions: int
    ) -> str:
        rtf = t_ns / wall_ns if wall_ns else 0.0
        armed = sum(1 for s in summaries if s.armed)
        in_air = sum(1 for s in summaries if not s.landed)
        done = len(channel.mission_exits)
        return (
            f"sim {t_ns / NS_PER_S:7.1f} s  x{rtf:5.1f} real time  armed {armed}/{len(summaries)}  "
            f"in air {in_air}  missions done {done}/{missions}"
        )


def _root_address(plan: LaunchPlan) -> str:
    """Where the root channel listens: ``--accept``'s address for joiners; with remote vehicles a TCP port (a
    ``harness join`` is told it); else a unix socket in the temp directory, which only this run's processes
    use. A frame through a unix socket costs the kernel half of what it costs through TCP over loopback
    (``bench_channel.py --case tcp,100,100,1 --case unix,100,100,1``: 4.4 and 2.4 ms of the channel process's
    CPU per tick with 100 missions). On Linux the socket is abstract (no file, nothing left after ``kill -9``);
    elsewhere a file the channel removes when it closes."""
    if plan.listen:
        return plan.listen
    if plan.remote_vehicles or not hasattr(socket, "AF_UNIX"):
        return ChannelConfig.address
    name = f"harness-run-{os.getpid()}-{secrets.token_hex(4)}"
    if sys.platform == "linux":
        return f"unix://@{name}"
    return f"unix://{Path(tempfile.gettempdir()) / f'{name}.sock'}"


def _all_joined(subs: list[tuple[str, str]], expected: int, sup: Children) -> bool:
    """Every process of the run has joined; a child that has exited before then never will: one line now,
    not a wait for the time-out (a mission that cannot start, a fork server that failed)."""
    for name, code in sup.poll_exits():
        raise SimulationError(f"the {name} process exited with {code} before the run started (see {name}.stderr)")
    return len(subs) >= expected


def _mission_argv(address: str, vehicle: int, m: MissionPlan, name: str | None = None) -> list[str]:
    return swarm.mission_argv(_python(), address, vehicle, m.script, m.args, name)


def _own_mission(plan: LaunchPlan, i: int) -> bool:
    return i < len(plan.missions) and plan.missions[i] is not None


def _pacing(pacer: Pacer, t_ns: int, wall0: int, now_ns: int) -> dict[str, float]:
    """``--speed``'s account (``summary.json``): the loop's wall time, sim time and how far it fell behind the
    schedule because the machine could not keep up (given up, plus the lag at the end; pauses not counted), so
    ``sim_s / (wall_s - behind_s)`` is the speed asked whenever pacing works, on an idle or a loaded machine."""
    behind = pacer.behind_ns + pacer.lag_ns(t_ns, now_ns)
    return {
        "speed": pacer.speed,
        "sim_s": t_ns / NS_PER_S,
        "wall_s": (now_ns - wall0) / NS_PER_S,
        "behind_s": behind / NS_PER_S,
    }


def _mission_count(plan: LaunchPlan) -> int:
    """Mission processes of a run: one per vehicle that has its own, plus the swarm mission."""
    return sum(1 for m in plan.missions[: plan.vehicles] if m) + (plan.swarm_mission is not None)


def _mission_name(plan: LaunchPlan, i: int) -> str | None:
    m = plan.missions[i] if i < len(plan.missions) else None
    if m is None and i < plan.vehicles:
        m = plan.swarm_mission
    return str(m.script) if m is not None else None
