"""The ``harness`` subcommands around a run: the channel on its own, ``join``, ``sweep``, ``plot``, and the
terminal helpers ``cli.py`` shares with them (progress lines, Ctrl-C as an interrupt, the tree options)."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from harness.core.errors import ScenarioError, StopSignal

if TYPE_CHECKING:
    from harness.run.cluster import ClusterShares
    from harness.scenario.plan import LaunchPlan
    from harness.sweep.runner import SweepProgress


def cmd_channel(a: argparse.Namespace, _rest: list[str]) -> int:
    from harness.channel import Channel, ChannelConfig
    from harness.core.secrets import channel_secret

    if a.secret:
        print("harness channel: --secret shows in ps; prefer --secret-file or $HARNESS_SECRET", file=sys.stderr)
    secret = channel_secret(a.secret, a.secret_file)
    cfg = ChannelConfig(
        address=a.listen,
        name=a.name,
        parent=a.parent,
        secret=secret,
        tick_hz=a.tick_hz,
        phase_every=a.phase_every,
        stall_timeout_s=a.stall_timeout,
    )
    ch = Channel(cfg)
    address = ch.bind()
    print(f"channel {cfg.name} listening on {address}", flush=True)
    signal.signal(signal.SIGTERM, lambda *_: ch.stop())
    try:
        ch.serve()
    except KeyboardInterrupt:
        return 130
    for f in ch.faults:
        print(f"fault: {f.peer} ({f.kind}) {f.reason}", file=sys.stderr)
    if ch.failure:
        print(f"run failed: {ch.failure}", file=sys.stderr)
        return 1
    return 0


def progress_printer() -> Callable[[str], None]:
    if sys.stderr.isatty():

        def live(line: str) -> None:
            sys.stderr.write("\r\033[K" + line)
            sys.stderr.flush()

        return live
    return lambda line: print(line, file=sys.stderr, flush=True)


def tree_options(a: argparse.Namespace) -> dict[str, Any]:
    """--remote-vehicles, --accept, --secret-file, --join-timeout: the root of a tree across machines."""
    from harness.run.tree import parse_workers, read_secret

    workers = {"workers": parse_workers(a.workers)} if getattr(a, "workers", None) else {}
    remote = getattr(a, "remote_vehicles", None)
    if remote is None and getattr(a, "accept", None) is None:
        return workers
    if remote is not None and remote < 0:
        raise ScenarioError(f"--remote-vehicles must be >= 0, got {remote}")
    return {
        "remote_vehicles": remote or 0,
        "listen": a.accept,
        "secret": read_secret(a.secret_file),
        "join_timeout_s": a.join_timeout,
        **workers,
    }


def cluster_plan(a: argparse.Namespace, plan: LaunchPlan) -> tuple[LaunchPlan, ClusterShares]:
    """``harness run --cluster local:K`` / ``--scheduler ADDRESS``: the root's plan (every vehicle remote, the
    root channel on an address the workers reach, the run's own secret) and the shares' placement."""
    import dataclasses

    from harness.run.cluster import ClusterShares, check_scheduler, parse_cluster
    from harness.scenario.limits import check_plan

    if a.cluster and a.scheduler:
        raise ScenarioError("give either --cluster local:K or --scheduler ADDRESS, not both")
    for option, given in (
        ("--workers", getattr(a, "workers", None)),
        ("--remote-vehicles", getattr(a, "remote_vehicles", None)),
        ("--accept", getattr(a, "accept", None)),
        ("--stdin", getattr(a, "stdin", False)),
        ("--swarm-mission", plan.swarm_mission),
        ("per-vehicle parameters", any(plan.params)),
    ):
        if given:
            raise ScenarioError(f"{option} cannot be used with --cluster/--scheduler (the workers fly every vehicle)")
    firmware = {f.value for f in plan.firmware} or {"px4"}
    if len(firmware) > 1:
        raise ScenarioError("--cluster/--scheduler: every vehicle must have the same --firmware")
    shares = ClusterShares(
        parse_cluster(a.cluster) if a.cluster else None,
        check_scheduler(a.scheduler) if a.scheduler else None,
        plan.vehicles,
        plan.missions[: plan.vehicles],
        firmware.pop(),
        plan.progress,
    )
    root = dataclasses.replace(
        plan,
        vehicles=0,
        remote_vehicles=plan.vehicles,
        missions=(),
        listen=shares.listen,
        secret=shares.secret.encode(),
        firmware=(),
    )
    check_plan(root, "", {"remote_vehicles": "--vehicles", "duration_s": "--duration", "seed": "--seed"})
    return root, shares


def cmd_join(a: argparse.Namespace, rest: list[str]) -> int:
    from harness.run.join import plan_from_args, run_join

    terminate_as_interrupt()
    result = run_join(plan_from_args(a, rest, progress_printer()))
    for vehicle, code in result.exits.items():
        print(f"  vehicle {vehicle}: mission exit {code}")
    if result.message:
        print(result.message, file=sys.stderr)
    return result.exit_code


def terminate_as_interrupt() -> None:
    """SIGINT and SIGTERM (Ctrl-C, a CI timeout, a supervisor) end a run cleanly: children stopped, summary
    written (saying which signal) — also when the shell started us in the background with SIGINT ignored.
    The first one stops the run; more while it stops are that same stop (calling this again re-arms it)."""

    stopping = False

    def handler(signum: int, frame: object) -> None:
        nonlocal stopping
        if stopping:  # a second Ctrl-C while the first one stops the run: the same stop, not a traceback
            return  # from the middle of the clean-up (which would leave the summary unwritten)
        stopping = True
        raise StopSignal(signum)

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    _STOP_HANDLERS.add(handler)


_STOP_HANDLERS: set[Callable[[int, object], None]] = set()


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def stop_handlers() -> dict[int, Any]:
    """SIGINT's and SIGTERM's handlers now (for :func:`after_the_command`)."""
    return {signum: signal.getsignal(signum) for signum in STOP_SIGNALS}


def after_the_command(before: dict[int, Any], *, exiting: bool) -> None:
    """The command is done (its run cleaned up, its summary written); the stop handlers it armed go.

    ``exiting`` (the ``harness`` command, the process ends now): a Ctrl-C while the interpreter exits is ignored.
    Without this, Python's exit puts SIGINT back to its default before native libraries flush (a second or two),
    and a second Ctrl-C in that window killed the process (exit -2 instead of the first's 0).
    Otherwise (``main`` called as a function: a test, a program embedding the harness) the handlers of ``before``
    come back: an ignored SIGTERM left behind would be inherited by every process the caller starts later."""
    for signum in STOP_SIGNALS:
        if signal.getsignal(signum) in _STOP_HANDLERS:
            signal.signal(signum, signal.SIG_IGN if exiting else before[signum])


def sweep_bar() -> Callable[[SweepProgress], None]:
    """The sweep's progress bar on stderr: redrawn in place on a terminal, a line per finished run otherwise."""
    tty = sys.stderr.isatty()
    last_seen: list[tuple[int, str]] = [(-1, "")]

    def show(pr: SweepProgress) -> None:
        line = pr.bar()
        if tty:
            sys.stderr.write("\r\033[K" + line)
            sys.stderr.flush()
        elif pr.done != last_seen[0][0] or (pr.last and pr.last != last_seen[0][1]):
            last_seen[0] = (pr.done, pr.last)
            print(line + (f"  {pr.last}" if pr.last else ""), file=sys.stderr, flush=True)

    return show


def cmd_sweep(a: argparse.Namespace, rest: list[str]) -> int:
    from harness.sweep.runner import SweepOptions, quiet_dask, run_sweep
    from harness.sweep.spec import build_sweep

    if rest:
        raise ScenarioError(f"harness sweep: unexpected arguments {' '.join(rest)}")
    spec = build_sweep(a.scenario, a.seeds, a.set)  # every combination validated before anything starts
    out = Path(a.out) if a.out else Path("runs") / f"sweep-{Path(a.scenario).stem}"
    opts = SweepOptions(out, a.scheduler, a.runs_per_worker, a.run_timeout, a.retry_failed)
    quiet_dask(a.verbose == 0)
    terminate_as_interrupt()
    print(f"sweep of {len(spec.runs)} runs into {out}", flush=True)
    outcome = run_sweep(spec, opts, sweep_bar())
    if sys.stderr.isatty():
        sys.stderr.write("\n")
    print(
        f"{'interrupted' if outcome.interrupted else 'done'}: {outcome.ran} run(s) this time, {outcome.kept} kept "
        f"from before, {len(outcome.failed)} not ok, in {outcome.wall_time_s:.1f} s; results in {out / 'results.csv'}"
    )
    for row in outcome.failed:
        print(f"  {row['run']}: {row.get('status')}: {row.get('message')}", file=sys.stderr)
    if outcome.interrupted:
        print("re-run the same command to finish the missing runs", file=sys.stderr)
        # Every run has stopped and results.csv is written. Dask's own exit hook would close the local cluster
        # gracefully once more (up to 10 s on a loaded machine) after the sweep closed it in a hurry: end now.
        sys.stdout.flush()
        sys.stderr.flush()
        logging.shutdown()
        os._exit(outcome.exit_code)
    if a.plot and not outcome.interrupted:
        from harness.sweep.plot import make_sweep_plots

        make_sweep_plots(out)
        print(f"plots: {out / 'index.html'}")
    return outcome.exit_code


def cmd_plot(a: argparse.Namespace, rest: list[str]) -> int:
    from harness.record.plot import make_plots

    if (Path(a.dir) / "sweep.json").is_file():
        from harness.sweep.plot import make_sweep_plots

        for path in make_sweep_plots(Path(a.dir)):
            print(path)
        return 0
    for path in make_plots(Path(a.dir)):
        print(path)
    if (Path(a.dir) / "summary.json").is_file():
        from harness.record.status import KILLED, read_summary

        summary = read_summary(Path(a.dir))
        if summary.get("status") == KILLED:
            print(f"note: {summary['message']}", file=sys.stderr)
    return 0
