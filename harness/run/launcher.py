"""The launcher behind ``harness run``: physics + root channel in this process, everything else supervised.

Processes of a run::

    harness run (this process)     physics (JSBSim, N vehicles) + root channel + recorder + progress
      ├─ autopilot host            all vehicles' autopilots and MAVLink servers (python -m harness.autopilot.host)
      ├─ network (optional)        the type-1 network subscriber
      └─ mission i (per vehicle)   harness mission SCRIPT on the sim clock (type 0)

The loop is the paper's tick, driven from here: physics frames → ``channel.step`` (autopilots answer,
missions run phase 0, the network phase 1) → motor commands → physics. The run ends when every mission
has exited, the duration is reached, a fault fails the run, or on Ctrl-C; every child is then stopped.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

from harness.autopilot.firmware import Firmware
from harness.core.clock import NS_PER_S, WALL, Clock
from harness.core.errors import ScenarioError, SimulationError
from harness.record.sample import VehicleSample, WorldEvent
from harness.record.sink import WorldSink, open_world
from harness.run.link import NativeLink
from harness.run.ports import allocate
from harness.run.result import RunResult, RunStatus, VehicleSummary, write_summary
from harness.scenario.plan import AutopilotPlacement, LaunchPlan, NetworkKind
from harness.simclock import protocol as p
from harness.simclock.channel import Channel, ChannelConfig

log = logging.getLogger(__name__)


def _python() -> str:
    return sys.executable


def _die_with_parent() -> None:
    """In the child, before exec: own process group, and SIGKILL when the harness dies (even kill -9)."""
    os.setpgid(0, 0)
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


class Children:
    """The run's child processes: output to files in the run directory, stopped as process groups.

    Every child runs in its own process group and is SIGKILLed by the kernel if this process dies; on
    ``stop()`` each group gets SIGTERM, then SIGKILL after ``grace_s``. Nothing outlives the run.
    """

    def __init__(self, run_dir: Path, grace_s: float = 2.0, clock: Clock = WALL) -> None:
        self.run_dir = run_dir
        self.grace_s = grace_s
        self.clock = clock
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self._reported: set[str] = set()

    def __enter__(self) -> Children:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self, name: str, argv: list[str], env: dict[str, str]) -> subprocess.Popen[bytes]:
        out = (self.run_dir / f"{name}.stdout").open("wb")
        err = (self.run_dir / f"{name}.stderr").open("wb")
        proc = subprocess.Popen(
            argv, stdin=subprocess.DEVNULL, stdout=out, stderr=err, env=env, preexec_fn=_die_with_parent
        )
        out.close()
        err.close()
        self.procs[name] = proc
        return proc

    def poll_exits(self) -> list[tuple[str, int]]:
        """Children that exited since the last call: (name, exit code; negative = killed by signal)."""
        out = []
        for name, proc in self.procs.items():
            if name not in self._reported and proc.poll() is not None:
                self._reported.add(name)
                out.append((name, proc.returncode))
        return out

    def stop(self) -> None:
        live = [p for p in self.procs.values() if p.poll() is None]
        for proc in live:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(proc.pid, signal.SIGTERM)
        deadline = self.clock.now_ns() + int(self.grace_s * NS_PER_S)
        for proc in live:
            left = max(0.0, (deadline - self.clock.now_ns()) / NS_PER_S)
            try:
                proc.wait(left)
            except subprocess.TimeoutExpired:
                pass
        for proc in self.procs.values():
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(proc.pid, signal.SIGKILL)  # the group: grandchildren such as mavsdk_server too
            proc.wait()


class Launcher:
    """Runs one plan. ``run()`` returns the result; the summary is written in any case. ``clock``: the wall
    clock of pacing, progress, the MAVLink side and the run's date (the sim clock is the physics)."""

    def __init__(self, plan: LaunchPlan, clock: Clock = WALL) -> None:
        if plan.vehicles < 1:
            raise ScenarioError(f"a run needs at least one vehicle, got {plan.vehicles}")
        self.plan = plan
        self.clock = clock
        plan.out.mkdir(parents=True, exist_ok=True)
        self.epoch_ns = clock.unix_ns() // NS_PER_S * NS_PER_S
        self.paused = threading.Event()
        """While set, the clock stands still (no ticks); MAVLink keeps answering on the wall clock."""
        self._pause_timer: threading.Timer | None = None
        self._aps: dict[int, Any] = {}
        """Autopilots inside this process (``autopilots = "in-process"``), by vehicle."""
        self.api_port_base, self.gcs_port = plan.api_port_base, plan.gcs_port
        self.tcp_port_base = plan.tcp_port_base or plan.api_port_base
        self._tcp_sim_clients = plan.api_remote_base == 0
        """A batch run (nothing sent unasked to hand-run tools): the ArduPilot vehicles' TCP clients are its
        missions, on sim time; `harness sitl` serves hand-run tools on the wall clock there."""

    def run(self) -> RunResult:
        from harness.fdm.physics import Physics, PhysicsConfig, WindConfig, WorldOrigin
        from harness.fdm.sensors import SensorConfig

        plan = self.plan
        n = plan.vehicles
        phys = Physics(
            PhysicsConfig(
                n_vehicles=n,
                seed=plan.seed,
                substep_hz=plan.physics_hz,
                tick_hz=plan.tick_hz,
                origin=WorldOrigin(*plan.origin),
                wind=WindConfig(steady_ned_m_s=plan.wind_ned_m_s, turbulence=plan.turbulence),
                spawn_ned_m=plan.spawn_ned_m,
                sensors=SensorConfig.for_gps(plan.gps, noise=plan.sensor_noise),
            )
        )
        channel = Channel(
            ChannelConfig(
                tick_hz=plan.tick_hz,
                phase_every=plan.phase_every,
                stall_timeout_s=plan.stall_timeout_s,
                epoch_ns=self.epoch_ns,
                name="root",
            )
        )
        channel.attach_physics()
        world = open_world(plan.out, self.epoch_ns, n, plan.origin, serve_port=plan.view_port)
        summaries = [VehicleSummary(i, _mission_name(plan, i)) for i in range(n)]
        faults: list[dict[str, Any]] = []
        status, message = RunStatus.OK, ""
        wall0 = self.clock.now_ns()
        t_ns = 0
        ports = allocate(n, plan.api_port_base, plan.gcs_port)
        self.api_port_base, self.gcs_port = ports.api_base, ports.gcs
        self.tcp_port_base = plan.tcp_port_base if plan.tcp_port_base is not None else ports.api_base
        local: list[Any] = []
        with (
            ports,
            Children(plan.out, clock=self.clock) as sup,
        ):  # the block stays this run's until every process has stopped
            try:
                if plan.progress is not None:
                    plan.progress(
                        f"MAVLink: ground station on udp port {self.gcs_port}; vehicle i listens on udp port "
                        f"{self.api_port_base}+i (each mission's udpin://0.0.0.0:14540 is redirected there)"
                    )
                    ardupilot = [i for i in range(n) if plan.firmware_of(i) is Firmware.ARDUPILOT]
                    if ardupilot:
                        step = plan.tcp_port_step
                        plan.progress(
                            f"MAVLink: ArduPilot vehicles {ardupilot} listen on tcp port {self.tcp_port_base}"
                            + (f"+{step}*i" if step != 1 else "+i")
                            + (f", and also send to udp {list(plan.gcs_extra_ports)}" if plan.gcs_extra_ports else "")
                        )
                if plan.on_view is not None and world.view is not None and world.view.grpc_url:
                    plan.on_view(world.view.grpc_url)
                if plan.autopilots == AutopilotPlacement.IN_PROCESS:
                    local = self._local_autopilots(channel)
                    world.attach_autopilots(self._aps)
                self._start_children(sup, channel.address)
                expected = (
                    (0 if local else 1)
                    + (1 if plan.network != NetworkKind.NONE else 0)
                    + sum(1 for m in plan.missions if m)
                )
                if not channel.wait_for(lambda subs: len(subs) >= expected, timeout_s=60.0):
                    raise SimulationError(
                        f"only {len(channel.subscribers())} of {expected} processes joined the channel within 60 s "
                        f"(see the *.stderr files in {plan.out})"
                    )
                status, message, t_ns = self._loop(phys, channel, world, summaries, sup)
            except KeyboardInterrupt:
                status, message = RunStatus.INTERRUPTED, "stopped by Ctrl-C"
            except SimulationError as exc:
                status, message = RunStatus.FAILED, str(exc)
            except Exception as exc:  # a bug must still stop every process and write the summary
                log.exception("the run failed")
                status, message = RunStatus.FAILED, f"internal error: {exc!r}"
            finally:
                channel.close("end of run")
                world.close()
                for handle in local:
                    handle.close()
        wall_s = (self.clock.now_ns() - wall0) / NS_PER_S
        t_ns = phys.t_ns
        exits = {e.vehicle: e for e in channel.mission_exits}
        for s in summaries:
            if s.mission is not None:
                e = exits.get(s.id)
                s.mission_exit_code = e.exit_code if e is not None else None
                if status == RunStatus.OK and (e is None or e.exit_code != 0):
                    status = RunStatus.FAILED
                    message = message or (
                        f"the mission of vehicle {s.id} was still running when the run ended at "
                        f"{phys.t_ns / NS_PER_S:.1f} s of sim time"
                        if e is None
                        else f"the mission of vehicle {s.id} exited with {e.exit_code} ({e.reason})"
                    )
        faults = [f.__dict__ for f in channel.faults]
        if any(s.crashed for s in summaries) and status == RunStatus.OK:
            status, message = RunStatus.FAILED, "a vehicle crashed"
        result = RunResult(status, t_ns / NS_PER_S, wall_s, summaries, faults, message)
        write_summary(
            plan.out,
            result,
            {
                "seed": plan.seed,
                "api_port_base": self.api_port_base,
                "gcs_port": self.gcs_port,
                "tick_hz": plan.tick_hz,
                "physics_hz": plan.physics_hz,
                "phase_every": plan.phase_every,
            },
        )
        return result

    def toggle_pause(self) -> None:
        """Pause or resume the clock (``harness run`` does this on SIGUSR1)."""
        if self.paused.is_set():
            self.paused.clear()
        else:
            self.paused.set()

    def _local_autopilots(self, channel: Channel) -> list[Any]:
        """Autopilots (and their MAVLink servers, tlogs, stored parameters) inside this process."""
        from harness.autopilot.autopilot import Autopilot, AutopilotConfig
        from harness.autopilot.mavlink.hub import MavlinkHub
        from harness.autopilot.mavlink.personality import core_param_defaults
        from harness.autopilot.mavlink.transport import PortsConfig
        from harness.autopilot.sitl import attach_mavlink, vehicle_ports

        plan = self.plan
        aps = {
            i: Autopilot(
                AutopilotConfig(
                    vehicle=i,
                    params={
                        **core_param_defaults(plan.firmware_of(i)),
                        **(plan.params[i] if i < len(plan.params) else {}),
                    },
                ),
                wall_clock=self.clock,
            )
            for i in range(plan.vehicles)
        }
        # each vehicle binds its API port; missions connect out to it, and nothing goes to anyone else's port
        ports = PortsConfig(
            api_port_base=plan.api_remote_base, api_local_port_base=self.api_port_base, gcs_port=self.gcs_port
        )
        hub = MavlinkHub(name="mavlink", clock=self.clock).start()  # one wall-clock thread serves every vehicle
        handles: list[Any] = []
        try:
            for i, ap in aps.items():
                fw = plan.firmware_of(i)
                vp = vehicle_ports(
                    ports, fw, self.tcp_port_base, plan.tcp_port_step, plan.gcs_extra_ports, self._tcp_sim_clients
                )
                handles.append(attach_mavlink(ap, vp, plan.out, None, hub, fw))
        except Exception as exc:
            for h in handles:
                h.close()
            hub.stop()
            if isinstance(exc, ScenarioError):  # a port taken by another simulator: one line, not a traceback
                raise SimulationError(str(exc)) from None
            raise
        handles.append(hub)

        self._aps = aps  # stepped by the channel through NativeLink, with the frame objects themselves
        return handles

    def _start_children(self, sup: Any, address: str) -> None:
        plan = self.plan
        env = dict(os.environ, HARNESS_CHANNEL=address, HARNESS_RUN_DIR=str(plan.out))
        vehicles = ",".join(str(i) for i in range(plan.vehicles))
        overrides = {str(i): p for i, p in enumerate(plan.params) if p}
        if plan.autopilots == AutopilotPlacement.IN_PROCESS:
            vehicles = ""
        if vehicles:
            sup.start(
                "autopilot",
                [
                    _python(),
                    "-m",
                    "harness.autopilot.sitl",
                    "--address",
                    address,
                    "--vehicles",
                    vehicles,
                    "--api-port-base",
                    str(plan.api_remote_base),
                    "--api-local-port-base",
                    str(self.api_port_base),
                    "--gcs-port",
                    str(self.gcs_port),
                    "--run-dir",
                    str(plan.out),
                    "--params",
                    json.dumps(overrides),
                    "--firmware",
                    ",".join(plan.firmware_of(i).value for i in range(plan.vehicles)),
                    "--tcp-port-base",
                    str(self.tcp_port_base),
                    "--tcp-port-step",
                    str(plan.tcp_port_step),
                    "--gcs-extra-ports",
                    ",".join(str(p) for p in plan.gcs_extra_ports),
                    *(["--tcp-sim-clients"] if self._tcp_sim_clients else []),
                ],
                env=env,
            )
        if plan.network != NetworkKind.NONE:
            sup.start(
                "network",
                [
                    _python(),
                    "-m",
                    "harness.net.subscriber",
                    "--address",
                    address,
                    "--model",
                    plan.network,
                    "--seed",
                    str(plan.seed),
                    "--params",
                    json.dumps(plan.network_params),
                ],
                env=env,
            )
        for i, m in enumerate(plan.missions[: plan.vehicles]):
            if m is None:
                continue
            menv = dict(
                env, HARNESS_VEHICLE=str(i), HARNESS_SYSID=str(i + 1), HARNESS_MAVLINK_PORT=str(self.api_port_base + i)
            )
            fw = plan.firmware_of(i)
            menv["HARNESS_FIRMWARE"] = fw.value
            if fw is Firmware.ARDUPILOT:  # SERIAL0: a script's tcp:127.0.0.1:5760 is sent here
                menv["HARNESS_MAVLINK_TCP_PORT"] = str(self.tcp_port_base + plan.tcp_port_step * i)
            sup.start(
                f"mission-{i}",
                [
                    _python(),
                    "-m",
                    "harness.cli",
                    "mission",
                    "--channel",
                    address,
                    "--vehicle",
                    str(i),
                    str(m.script),
                    "--",
                    *m.args,
                ],
                env=menv,
            )

    def _loop(
        self, phys: Any, channel: Channel, world: WorldSink, summaries: list[VehicleSummary], sup: Any
    ) -> tuple[RunStatus, str, int]:
        plan = self.plan
        n = plan.vehicles
        record_every = max(1, round(plan.tick_hz / plan.record_hz))
        end_ns = None if plan.duration_s is None else round(plan.duration_s * NS_PER_S)
        missions = sum(1 for m in plan.missions[:n] if m)
        frames = phys.frames()
        link = NativeLink(channel, self._aps)
        paused_once = False
        wall0 = self.clock.now_ns()
        last_progress = wall0
        motors: list[tuple[float, ...]] = [(0.0, 0.0, 0.0, 0.0)] * n
        while True:
            t_ns = phys.t_ns
            tick = phys.tick
            if end_ns is not None and t_ns >= end_ns:
                return RunStatus.OK, "", t_ns
            if missions and len(channel.mission_exits) >= missions:
                return RunStatus.OK, "", t_ns
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
                wall0 += stalled  # pacing resumes from here, it does not rush to catch up
                world.event(t_ns, WorldEvent.RESUMED, {"paused_wall_s": stalled / NS_PER_S})
            if plan.speed is not None:
                lag = wall0 + int(t_ns / plan.speed) - self.clock.now_ns()
                self.clock.sleep_ns(lag)
            tick_start = self.clock.now_ns()
            etas = link.exchange(t_ns, tick, frames)
            for e in etas:
                motors[e.vehicle] = e.motors
                summaries[e.vehicle].armed = p.unpack_status(e.status)[0]
            if tick % record_every == 0:
                now = self.clock.now_ns()
                for f in frames:
                    tr = f.truth
                    world.vehicle(
                        VehicleSample(
                            t_ns,
                            f.vehicle,
                            tr.pos_ned_m,
                            tr.quat,
                            tr.vel_ned_m_s,
                            tr.lat_deg,
                            tr.lon_deg,
                            tr.alt_amsl_m,
                            motors[f.vehicle],
                            tr.on_ground,
                            tr.crashed,
                        )
                    )
                world.tick(t_ns, tick, (now - wall0) / NS_PER_S, (now - tick_start) / 1e3)
            frames = phys.step(motors)
            for f in frames:
                s = summaries[f.vehicle]
                alt = -f.truth.pos_ned_m[2]
                if alt > s.max_altitude_m:
                    s.max_altitude_m = alt
                s.final_position_ned_m = f.truth.pos_ned_m
                s.landed = f.truth.on_ground
                if f.truth.crashed and not s.crashed:
                    s.crashed = True
                    world.event(t_ns, WorldEvent.CRASH, {"vehicle": f.vehicle})
            if tick % 50 == 0:  # every 0.2 s of sim time: a child's death is noticed, waitpid stays cheap
                for name, code in sup.poll_exits():
                    if name in ("autopilot", "network"):
                        raise SimulationError(f"the {name} process exited with {code} (see {name}.stderr)")
            if plan.progress is not None and self.clock.now_ns() - last_progress > 500_000_000:
                last_progress = self.clock.now_ns()
                plan.progress(self._progress_line(t_ns, last_progress - wall0, summaries, channel, missions))

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


def _mission_name(plan: LaunchPlan, i: int) -> str | None:
    m = plan.missions[i] if i < len(plan.missions) else None
    return str(m.script) if m is not None else None
