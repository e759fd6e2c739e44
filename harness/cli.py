"""The ``harness`` command. User-facing output and exit codes live here, nowhere else."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import os
import signal
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from harness import cli_types as ct
from harness.cli_run import (
    after_the_command,
    cluster_plan,
    cmd_channel,
    cmd_join,
    cmd_plot,
    cmd_sweep,
    progress_printer,
    stop_handlers,
    terminate_as_interrupt,
    tree_options,
)
from harness.core import lifeline
from harness.core.endpoints import GCS_PORT
from harness.core.errors import HarnessError, ScenarioError
from harness.core.files import script_file
from harness.core.limits import ERROR_CHARS, cut

if TYPE_CHECKING:
    from harness.record.viewer import NativeViewer
    from harness.run.launcher import Launcher
    from harness.scenario.plan import LaunchPlan, MissionPlan


def _cmd_mission(a: argparse.Namespace, script_args: list[str]) -> int:
    from harness.simclock.mission import MissionHooks, MissionSpec, run_mission

    channel = a.channel or os.environ.get("HARNESS_CHANNEL")
    if not channel:
        raise ScenarioError("harness mission: no channel given (use --channel ADDRESS or set HARNESS_CHANNEL)")
    vehicle = a.vehicle if a.vehicle is not None else int(os.environ.get("HARNESS_VEHICLE", "0"))
    script = script_file(Path(a.script), "script")
    name = a.name or f"mission:{script.name}:{vehicle}"
    hooks = MissionHooks(
        report=lambda line: print(f"harness mission: {line}", file=sys.stderr), end_process=_end_mission
    )
    try:
        code = run_mission(MissionSpec(script, tuple(script_args), channel, vehicle, name), hooks)
    except ScenarioError as exc:
        print(f"harness mission: {exc}", file=sys.stderr)
        code = 2
    except Exception as exc:
        print(f"harness mission: {exc}", file=sys.stderr)
        code = 1
    _end_mission(code)


def _end_mission(code: int) -> NoReturn:
    """End a mission process at once: a library may have left a non-daemon thread behind, and whatever the
    script started (mavsdk_server) must not outlive it."""
    from harness.core.lifeline import exit_now
    from harness.simclock.mission import kill_descendants

    kill_descendants()
    exit_now(code)


def _plan_from_args(a: argparse.Namespace, script_args: list[str] | None = None, checked: bool = True) -> LaunchPlan:
    from harness.net.model import NetworkKind
    from harness.scenario.plan import LaunchPlan, MissionPlan

    if getattr(a, "scenario", None):
        from harness.scenario.config import load_scenario

        if a.mission or a.vehicles is not None:
            raise ScenarioError("give either a scenario file or --vehicles/--mission, not both")
        return load_scenario(
            a.scenario,
            swarm_mission=_swarm_mission(a, script_args),
            **tree_options(a),
            sets=_assignments(getattr(a, "set", None) or []),
            out=Path(a.out) if a.out else None,
            seed=a.seed,
            speed=_speed(a),
            duration_s=a.duration,
            network=a.network,
            signing_key_file=a.signing_key_file,
            progress=None if getattr(a, "no_progress", False) else progress_printer(),
            **_firmware_options(a),
        )
    if getattr(a, "set", None):
        raise ScenarioError("--set changes a scenario file: give one (harness run SCENARIO.toml --set PATH=VALUE)")

    missions = [MissionPlan(Path(m), tuple(script_args or ())) for m in a.mission]
    for m in missions:
        script_file(m.script, "--mission")
    vehicles = a.vehicles if a.vehicles is not None else max(1, len(missions))
    swarm_mission = _swarm_mission(a, script_args)
    if swarm_mission is not None and a.vehicles is None and not missions:
        raise ScenarioError("--swarm-mission: say how many vehicles it commands with --vehicles N")
    if len(missions) == 1 and vehicles > 1:
        missions = missions * vehicles  # one script flies every vehicle
    return (_checked if checked else _same)(
        LaunchPlan(
            vehicles=vehicles,
            out=Path(a.out) if a.out else Path("runs") / time.strftime("%Y%m%d-%H%M%S"),
            missions=tuple(missions),
            swarm_mission=swarm_mission,
            seed=a.seed or 0,
            speed=_speed(a),
            duration_s=a.duration,
            network=NetworkKind(a.network or "none"),
            progress=None if getattr(a, "no_progress", False) else progress_printer(),
            pause_at_s=a.pause_at,
            pause_wall_s=a.pause_for,
            signing_key_file=a.signing_key_file,
            **_firmware_options(a),
            **tree_options(a),
        )
    )


_SPEED_NOT_GIVEN = math.nan
"""``--speed``'s default: not given (``--speed max`` is None)."""


def _speed(a: argparse.Namespace) -> float | None:
    """``--speed``; else PX4 SITL's ``PX4_SIM_SPEED_FACTOR``; else real time for ``harness sitl``, as fast as
    possible (or the scenario's ``speed``) otherwise."""
    from harness.scenario.sitl_defaults import sitl_speed

    given = getattr(a, "speed", _SPEED_NOT_GIVEN)
    if given is not _SPEED_NOT_GIVEN:
        return given
    env = sitl_speed(os.environ)
    if env is not None:
        return env
    return 1.0 if a.command == "sitl" else None


_CLI_NAMES = {
    "vehicles": "--vehicles",
    "duration_s": "--duration",
    "speed": "--speed",
    "seed": "--seed",
    "tcp_port_base": "--tcp-port-base",
    "view_port": "--view-port",
    "pause_at_s": "--pause-at",
    "pause_wall_s": "--pause-for",
    "signing_key_file": "--signing-key-file",
    "remote_vehicles": "--remote-vehicles",
    "join_timeout_s": "--join-timeout",
}


def _same(plan: LaunchPlan) -> LaunchPlan:
    return plan


def _checked(plan: LaunchPlan) -> LaunchPlan:
    """Every setting within its bounds (``scenario/limits.py``) before anything starts."""
    from harness.scenario.limits import check_plan

    check_plan(plan, "", _CLI_NAMES)
    return plan


def _swarm_mission(a: argparse.Namespace, script_args: list[str] | None) -> MissionPlan | None:
    """``--swarm-mission PATH``: one script for every vehicle (``docs/swarm.md``)."""
    from harness.scenario.plan import MissionPlan

    path = getattr(a, "swarm_mission", None)
    if path is None:
        return None
    script_file(Path(path), "--swarm-mission")
    return MissionPlan(Path(path), tuple(script_args or ()))


def _firmware_options(a: argparse.Namespace) -> dict[str, Any]:
    """--firmware (one for all vehicles or comma-separated per vehicle) and, for `harness sitl`, the
    addresses ArduPilot SITL users expect: SERIAL0 on TCP 5760 + 10 i, UDP outputs 14550 and 14551."""
    from harness.autopilot.firmware import Firmware

    out: dict[str, Any] = {}
    if getattr(a, "firmware", None):
        out["firmware"] = tuple(Firmware.parse(f, "--firmware") for f in a.firmware.split(",") if f.strip())
    tcp_base = getattr(a, "tcp_port_base", None)
    if a.command == "sitl":
        out["tcp_port_base"] = tcp_base if tcp_base is not None else 5760
        out["tcp_port_step"] = 10
        out["gcs_extra_ports"] = (14551,)
    elif tcp_base is not None:
        out["tcp_port_base"] = tcp_base
    return out


def _assignments(texts: list[str]) -> list[tuple[str, object]]:
    """``--set PATH=VALUE`` options of ``harness run`` (one value each; the value is TOML or a bare word)."""
    from harness.scenario.config import parse_value

    out: list[tuple[str, object]] = []
    for text in texts:
        path, eq, value = text.partition("=")
        if not eq or not path.strip():
            raise ScenarioError(f"--set {text}: expected PATH=VALUE, e.g. --set wind.north_m_s=4")
        out.append((path.strip(), parse_value(value.strip())))
    return out


def _live_view(a: argparse.Namespace, plan: LaunchPlan) -> tuple[LaunchPlan, list[NativeViewer]]:
    """``--view [native|web]``: the plan serves its 3D view live; the viewer starts once the stream is up."""
    import dataclasses

    from harness.core.freeport import free_tcp_port
    from harness.record.viewer import NativeViewer, ViewMode, WebViewer, require_rerun

    mode = ViewMode(a.view)
    require_rerun(f"--view {mode.value}")
    natives: list[NativeViewer] = []
    if mode is ViewMode.WEB:
        web = WebViewer(a.view_port)

        def on_view(stream: str) -> None:
            print(f"3D view (web viewer): {web.start(stream)}", flush=True)

    else:
        native = NativeViewer("", ("--new",))  # checks for a display before the run starts

        def on_view(stream: str) -> None:
            native.argv[-1] = stream
            natives.append(native.start())
            print(f"3D view: native viewer on {stream}", flush=True)

    return dataclasses.replace(plan, view_port=free_tcp_port(), on_view=on_view), natives


def _cmd_run(a: argparse.Namespace, rest: list[str]) -> int:
    from harness.run.launcher import Launcher

    terminate_as_interrupt()
    if getattr(a, "cluster", None) or getattr(a, "scheduler", None):
        return _cmd_run_on_cluster(a, rest)
    plan = _plan_from_args(a, rest)
    if getattr(a, "stdin", False):
        if sum(m is not None for m in plan.missions[: plan.vehicles]) + (plan.swarm_mission is not None) != 1:
            raise ScenarioError("--stdin hands the terminal to one mission: run exactly one")
        plan = dataclasses.replace(plan, mission_stdin=True)
    natives: list[NativeViewer] = []
    if getattr(a, "view", None):
        plan, natives = _live_view(a, plan)
    try:
        return _run_plan(a, plan, natives, Launcher(plan))
    finally:
        for viewer in natives:
            viewer.stop()


def _cmd_run_on_cluster(a: argparse.Namespace, rest: list[str]) -> int:
    """``harness run --cluster local:K`` / ``--scheduler ADDRESS``: the vehicles on a Dask cluster's workers."""
    from harness.run.launcher import Launcher

    plan, shares = cluster_plan(a, _plan_from_args(a, rest, checked=False))
    try:
        shares.open()  # the workers measured and the vehicles split; one line when they cannot hold them
        return _run_plan(a, plan, [], Launcher(plan, remote=shares))
    finally:
        shares.stop(plan.out, hurry=True)


def _run_plan(a: argparse.Namespace, plan: LaunchPlan, natives: list[NativeViewer], launcher: Launcher) -> int:
    signal.signal(signal.SIGUSR1, lambda *_: launcher.toggle_pause())  # kill -USR1 <pid> pauses / resumes
    result = launcher.run()
    if sys.stderr.isatty():
        sys.stderr.write("\n")
    print(
        f"{result.status}: {result.sim_time_s:.1f} s simulated in {result.wall_time_s:.1f} s "
        f"(x{result.real_time_factor:.1f} real time); results in {plan.out}"
    )
    if result.message:
        print(result.message, file=sys.stderr)
    for v in result.vehicles:
        print(
            f"  vehicle {v.id}: mission exit {_exit_text(v.mission_exit_code, v.mission_exit_reason)}, "
            f"max altitude {v.max_altitude_m:.1f} m, "
            f"final NED {tuple(round(x, 1) for x in v.final_position_ned_m)}, landed {v.landed}"
        )
    if a.plot:
        from harness.record.plot import make_plots

        make_plots(plan.out)
        print(f"plots: {plan.out / 'index.html'}")
    from harness.record.sink import INSTALL_HINT, rerun_available

    rrd = plan.out / "world.rrd"
    if rrd.is_file() and str(rrd) not in result.incomplete:
        print(f"3D view: harness view {plan.out}")
    elif not rerun_available():
        print(f"3D view: not recorded ({INSTALL_HINT})")
    if natives:
        terminate_as_interrupt()  # re-armed: a Ctrl-C that stopped the run is spent, the next closes the viewer
    for viewer in natives:
        print("the viewer stays open until you close it (Ctrl-C closes it too)", flush=True)
        try:
            viewer.wait()
        except KeyboardInterrupt:
            pass
    return result.exit_code


def _exit_text(code: int | None, reason: str) -> str:
    """``0``, ``1``, ``-9 (killed by SIGKILL)``, ``-1 (dropped: stalled ...)``: the code, and how it came to be
    when the code alone does not say."""
    if code is None:
        return "none (still running at the end)"
    return f"{code} ({reason})" if code < 0 and reason else str(code)


def _cmd_view(a: argparse.Namespace, rest: list[str]) -> int:
    """Open a run's ``world.rrd`` in the native viewer, or serve it to a browser (``--web``)."""
    from harness.record.viewer import NativeViewer, require_rerun, serve_file_web

    run_dir = Path(a.dir)
    rrd = run_dir / "world.rrd" if run_dir.is_dir() else run_dir
    require_rerun("harness view")
    if not rrd.is_file():
        raise ScenarioError(
            f"harness view: {rrd} does not exist (runs write world.rrd when the view extra is installed; "
            "give a run directory such as runs/demo)"
        )
    terminate_as_interrupt()
    if a.web:
        proc, url = serve_file_web(rrd, a.port)
        print(f"3D view (web viewer): {url}  (Ctrl-C stops)", flush=True)
        try:
            return proc.wait()
        except KeyboardInterrupt:
            return 0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    viewer = NativeViewer(str(rrd), ("--new",)).start()
    try:
        return viewer.wait()
    except KeyboardInterrupt:
        return 0
    finally:
        viewer.stop()


def _cmd_demo(a: argparse.Namespace, rest: list[str]) -> int:
    from harness.bundled import DEMO, example

    a.mission = [str(example(DEMO).path)]
    a.vehicles = a.vehicles or 3
    a.network = a.network or "builtin"  # the swarm flocks over the radio
    a.plot = True
    return _cmd_run(a, rest)


def _cmd_examples(a: argparse.Namespace, rest: list[str]) -> int:
    """List the example missions, or copy some into a folder."""
    from harness.bundled import copy_examples, examples, examples_dir

    if a.action == "list":
        if a.names or a.all:
            raise ScenarioError("`harness examples` lists them all; to copy some: harness examples copy NAME…")
        items = examples()
        width = max(len(e.name) for e in items)
        for e in items:
            print(f"{e.name:<{width}}  {e.summary}")
        print(f"\n{len(items)} example missions in {examples_dir()}")
        print(
            "copy one here: harness examples copy takeoff_and_land.py; fly it: harness run --mission takeoff_and_land.py"
        )
        return 0
    if a.action == "path":
        print(examples_dir())
        return 0
    if bool(a.names) == a.all:
        raise ScenarioError("name the examples to copy (`harness examples` lists them), or give --all alone")
    names = [e.name for e in examples()] if a.all else a.names
    for path in copy_examples(names, Path(a.to), force=a.force):
        print(path)
    return 0


def _cmd_sitl(a: argparse.Namespace, rest: list[str]) -> int:
    """Vehicles at real time for a ground station and hand-run scripts, until Ctrl-C."""
    from harness.run.launcher import Launcher
    from harness.run.result import RunStatus

    a.mission, a.duration, a.plot = [], None, False
    terminate_as_interrupt()
    # hand-run MAVSDK scripts listen on 14540 + i (udpin://0.0.0.0:14540 reaches vehicle 0)
    # ... and a ground station finds them on 14550 (QGroundControl's, PX4 SITL's): a destination, listened on or not
    plan = dataclasses.replace(_plan_from_args(a), api_remote_base=14540, gcs_port=GCS_PORT)
    natives: list[NativeViewer] = []
    if a.view:
        plan, natives = _live_view(a, plan)
    print(f"{plan.vehicles} vehicle(s) at x{plan.speed or 'max'} real time; Ctrl-C stops.", flush=True)
    try:
        result = Launcher(plan).run()
    finally:
        for viewer in natives:
            viewer.stop()
    if result.status not in (RunStatus.OK, RunStatus.INTERRUPTED):
        print(f"harness sitl: {result.status}: {result.message}", file=sys.stderr)
        return 1
    return 0


def _add_run_options(r: argparse.ArgumentParser) -> None:
    r.add_argument("--vehicles", type=ct.vehicles, default=None, help="number of vehicles (default: one per --mission)")
    r.add_argument("--mission", action="append", default=[], help="mission script (one: every vehicle flies it)")
    r.add_argument(
        "--swarm-mission",
        default=None,
        metavar="PATH",
        help="one script that commands every vehicle (it reads their addresses from $HARNESS_VEHICLES)",
    )
    r.add_argument(
        "--speed",
        type=ct.speed,
        default=_SPEED_NOT_GIVEN,
        help="'max' (default; $PX4_SIM_SPEED_FACTOR when set) or a real-time factor",
    )
    r.add_argument("--duration", type=ct.duration, default=None, help="sim-time limit in seconds")
    r.add_argument("--network", choices=["builtin", "ns3", "none"], default=None)
    r.add_argument("--seed", type=ct.seed, default=None)
    r.add_argument("--out", default=None, help="run directory (default runs/<timestamp>)")
    r.add_argument("--plot", action="store_true", help="write plots into the run directory at the end")
    r.add_argument(
        "--firmware",
        default=None,
        metavar="px4|ardupilot",
        help="the personality of the vehicles (comma-separated: per vehicle); default px4",
    )
    r.add_argument(
        "--tcp-port-base",
        type=ct.port,
        default=None,
        metavar="PORT",
        help="ArduPilot vehicles' SERIAL0 TCP ports (sitl: 5760 + 10 i; run: the run's own port block)",
    )
    r.add_argument(
        "--view",
        nargs="?",
        const="native",
        choices=["native", "web"],
        default=None,
        help="watch the run live in Rerun: the native viewer (default) or 'web' (serves the web viewer, prints its URL)",
    )
    r.add_argument("--view-port", type=ct.port, default=None, help="HTTP port of the web viewer (default: a free one)")
    r.add_argument(
        "--pause-at",
        type=ct.sim_time,
        default=None,
        metavar="SIM_S",
        help="stall test: stop the clock at this sim time",
    )
    r.add_argument("--pause-for", type=ct.wait, default=5.0, metavar="WALL_S", help="... for this long (wall seconds)")
    r.add_argument(
        "--set", action="append", default=[], metavar="PATH=VALUE", help="change a scenario-file value (TOML)"
    )
    r.add_argument("--no-progress", action="store_true", help="no progress line on stderr (batch use)")
    r.add_argument(
        "--signing-key-file",
        type=Path,
        default=None,
        metavar="PATH",
        help="MAVLink 2 signing on every link: a file with the 32-byte key as 64 hex characters",
    )
    r.add_argument(
        "--remote-vehicles", type=int, default=None, metavar="M", help="M more vehicles flown by `harness join`"
    )
    r.add_argument("--accept", default=None, metavar="tcp://HOST:PORT", help="the root channel's address for joiners")
    r.add_argument("--secret-file", default=None, help="file holding the shared secret (or $HARNESS_SECRET)")
    r.add_argument(
        "--workers",
        default=None,
        metavar="N|auto",
        help="spread the vehicles' physics and autopilots over N processes (default auto: one per core, "
        "with at least 2 vehicles each)",
    )
    r.add_argument("--join-timeout", type=float, default=600.0, help="wall seconds to wait for the remote vehicles")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("uav-harness")
    except PackageNotFoundError:
        return "(not installed: run from a source tree)"


def build_parser() -> argparse.ArgumentParser:
    ap = ct.OneLineParser(prog="harness", description="Lockstep co-simulation of multirotor UAV swarms.")
    ap.add_argument("-v", "--verbose", action="count", default=0)
    ap.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = ap.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="a headless batch run: physics, autopilots, network and missions")
    r.add_argument("scenario", nargs="?", default=None, help="scenario file (TOML); or use --vehicles/--mission")
    _add_run_options(r)
    r.add_argument(
        "--stdin",
        action="store_true",
        help="hand this terminal's stdin to the run's one mission and show its output here (prompt-driven scripts)",
    )
    r.add_argument(
        "--cluster",
        default=None,
        metavar="local:K",
        help="fly the vehicles (autopilots, missions) on a local Dask cluster of K worker processes",
    )
    r.add_argument(
        "--scheduler",
        default=None,
        metavar="tcp://HOST:8786",
        help="fly the vehicles on the workers of this Dask cluster (this machine keeps the physics and recordings)",
    )
    r.set_defaults(func=_cmd_run)

    d = sub.add_parser(
        "demo",
        help="3 vehicles flock over the radio to a waypoint and home (the swarm_demo.py example); plots and 3D view",
    )
    _add_run_options(d)
    d.set_defaults(func=_cmd_demo)

    ex = sub.add_parser("examples", help="list the example missions, or copy some into a folder of yours")
    ex.add_argument("action", nargs="?", choices=("list", "copy", "path"), default="list")
    ex.add_argument("names", nargs="*", metavar="NAME", help="examples to copy (e.g. takeoff_and_land.py)")
    ex.add_argument("--all", action="store_true", help="copy every example")
    ex.add_argument("--to", default=".", metavar="DIR", help="folder to copy them into (default: this one)")
    ex.add_argument("--force", action="store_true", help="overwrite files of the same name there")
    ex.set_defaults(func=_cmd_examples)

    st = sub.add_parser("sitl", help="vehicles at real time for QGroundControl and hand-run scripts")
    _add_run_options(st)
    st.set_defaults(func=_cmd_sitl)

    vw = sub.add_parser("view", help="open a run's 3D view (world.rrd) in Rerun's viewer")
    vw.add_argument("dir", help="run directory (or a .rrd file)")
    vw.add_argument("--web", action="store_true", help="serve the web viewer instead and print its URL")
    vw.add_argument("--port", type=ct.port, default=None, help="HTTP port for --web (default: a free one)")
    vw.set_defaults(func=_cmd_view)

    pl = sub.add_parser("plot", help="plots and an HTML page from a run directory")
    pl.add_argument("dir")
    pl.set_defaults(func=cmd_plot)

    sw = sub.add_parser("sweep", help="a scenario over seeds and --set values, on Dask (local cluster by default)")
    sw.add_argument("scenario", help="scenario file (TOML)")
    sw.add_argument("--seeds", default=None, help="0-9, 0,3,7 or 0-3,10 (default: the file's seed)")
    sw.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="PATH=V1,V2,...",
        help="sweep a scenario value (dotted path, TOML values); repeat for a cartesian product",
    )
    sw.add_argument("--out", default=None, help="sweep directory (default runs/sweep-<scenario>)")
    sw.add_argument("--scheduler", default=None, help="Dask scheduler address (default: a local cluster)")
    sw.add_argument("--runs-per-worker", type=int, default=None, help="runs at once per worker")
    sw.add_argument("--run-timeout", type=float, default=None, metavar="WALL_S", help="stop a run after this long")
    sw.add_argument("--retry-failed", action="store_true", help="on a re-run, run failed runs again too")
    sw.add_argument("--plot", action="store_true", help="write the sweep's plots at the end")
    sw.set_defaults(func=cmd_sweep)

    m = sub.add_parser("mission", help="run an unmodified script as a type-0 subscriber on the sim clock")
    m.add_argument("script")
    m.add_argument(
        "--vehicle",
        type=ct.integer(-1, 254),
        default=None,
        help="vehicle index (default $HARNESS_VEHICLE or 0; -1: a swarm mission)",
    )
    m.add_argument("--channel", default=None, help="channel address (default $HARNESS_CHANNEL)")
    m.add_argument("--name", default=None)
    m.set_defaults(func=_cmd_mission)

    j = sub.add_parser("join", help="fly some vehicles of a run on this machine: a child channel of its root")
    j.add_argument("address", help="the root's address (harness run --accept …)")
    j.add_argument("--first-vehicle", type=int, required=True, help="index of the first vehicle flown here")
    j.add_argument("--vehicles", type=int, default=1, help="how many vehicles this machine flies")
    j.add_argument("--mission", action="append", default=[], help="mission script (one: every vehicle here)")
    j.add_argument("--firmware", default="px4", metavar="px4|ardupilot")
    j.add_argument("--out", default=None, help="directory for this machine's tlogs and mission output")
    j.add_argument("--name", default=None, help="this child channel's name in the run (default join:HOST:PID)")
    j.add_argument("--secret-file", default=None, help="file holding the shared secret (or $HARNESS_CHANNEL_SECRET)")
    j.set_defaults(func=cmd_join)

    c = sub.add_parser("channel", help="run a channel on its own (for a tree across machines)")
    c.add_argument("--listen", default="tcp://127.0.0.1:5760")
    c.add_argument("--parent", default=None, help="parent channel address: run as a child")
    c.add_argument("--name", default="channel")
    c.add_argument("--secret-file", default=None, metavar="PATH", help="file holding the shared secret")
    c.add_argument(
        "--secret", default=None, help="shared secret (shows in ps: prefer --secret-file or $HARNESS_SECRET)"
    )
    c.add_argument("--tick-hz", type=ct.rate, default=250.0)
    c.add_argument("--phase-every", type=ct.count, default=5)
    c.add_argument("--stall-timeout", type=ct.wait, default=10.0)
    c.set_defaults(func=cmd_channel)
    return ap


def main(argv: Sequence[str] | None = None, *, exiting: bool = False) -> int:
    """``harness ARGV``: the exit code. ``exiting``: the process ends when it returns (the ``harness`` command);
    called as a function, it leaves the process's signal handlers as it found them."""
    lifeline.hold_on()  # started by a run (Children): die with it, before anything else
    argv = list(sys.argv[1:] if argv is None else argv)
    script_args: list[str] = []
    if "--" in argv:
        i = argv.index("--")
        argv, script_args = argv[:i], argv[i + 1 :]
    ap = build_parser()
    a, unknown = ap.parse_known_args(argv)
    if unknown and a.command != "mission":
        ap.error(f"unrecognized arguments: {' '.join(unknown)}")
    logging.basicConfig(
        level=logging.DEBUG if a.verbose > 1 else logging.INFO if a.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    if a.verbose == 0 and a.command != "mission":  # (a mission records nothing: no Rerun, no mcap to import)
        from harness.record.sink import QUIET_RERUN_LOG

        os.environ.setdefault("RUST_LOG", QUIET_RERUN_LOG)
    before = stop_handlers()
    try:
        return int(a.func(a, unknown + script_args))
    except HarnessError as exc:
        print(f"harness: {cut(str(exc), ERROR_CHARS)}", file=sys.stderr)  # one line, however long its values
        return 2
    finally:
        after_the_command(before, exiting=exiting)


def command() -> int:
    """The ``harness`` command (console script and ``python -m harness.cli``): :func:`main` in a process that
    ends when it returns."""
    return main(exiting=True)


if __name__ == "__main__":
    sys.exit(command())
