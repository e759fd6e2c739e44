"""The ``harness`` command. User-facing output and exit codes live here, nowhere else."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

from harness.errors import HarnessError, ScenarioError


def _cmd_mission(a: argparse.Namespace, script_args: list[str]) -> int:
    from harness.simclock.mission import MissionSpec, main_mission

    channel = a.channel or os.environ.get("HARNESS_CHANNEL")
    if not channel:
        raise ScenarioError("harness mission: no channel given (use --channel ADDRESS or set HARNESS_CHANNEL)")
    vehicle = a.vehicle if a.vehicle is not None else int(os.environ.get("HARNESS_VEHICLE", "0"))
    script = Path(a.script)
    if not script.is_file():
        raise ScenarioError(f"harness mission: script {script} does not exist")
    name = a.name or f"mission:{script.name}:{vehicle}"
    main_mission(MissionSpec(script, tuple(script_args), channel, vehicle, name))
    return 0  # not reached


def _cmd_channel(a: argparse.Namespace, _rest: list[str]) -> int:
    from harness.simclock.channel import Channel, ChannelConfig

    secret = (a.secret or os.environ.get("HARNESS_CHANNEL_SECRET") or "").encode() or None
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


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="harness", description="Lockstep co-simulation of multirotor UAV swarms.")
    ap.add_argument("-v", "--verbose", action="count", default=0)
    sub = ap.add_subparsers(dest="command", required=True)

    m = sub.add_parser("mission", help="run an unmodified script as a type-0 subscriber on the sim clock")
    m.add_argument("script")
    m.add_argument("--vehicle", type=int, default=None, help="vehicle index (default $HARNESS_VEHICLE or 0)")
    m.add_argument("--channel", default=None, help="channel address (default $HARNESS_CHANNEL)")
    m.add_argument("--name", default=None)
    m.set_defaults(func=_cmd_mission)

    c = sub.add_parser("channel", help="run a channel on its own (for a tree across machines)")
    c.add_argument("--listen", default="tcp://127.0.0.1:5760")
    c.add_argument("--parent", default=None, help="parent channel address: run as a child")
    c.add_argument("--name", default="channel")
    c.add_argument("--secret", default=None, help="shared secret (or $HARNESS_CHANNEL_SECRET)")
    c.add_argument("--tick-hz", type=float, default=250.0)
    c.add_argument("--phase-every", type=int, default=5)
    c.add_argument("--stall-timeout", type=float, default=10.0)
    c.set_defaults(func=_cmd_channel)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
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
    try:
        return int(a.func(a, unknown + script_args))
    except HarnessError as exc:
        print(f"harness: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
