"""The network process: a type-1 subscriber that carries phase-0 packets through a network model.

    python -m harness.net.subscriber --config RUN/network.json     # as harness run starts it
    python -m harness.net.subscriber --address tcp://127.0.0.1:5760 --model builtin --seed 1 --params '{}'

On every BEGIN-TICK-1 it runs the model over the interval with the tick's positions and packets, sends a
DELIVER for every packet that arrives (broadcasts expanded per receiver), then END-TICK-1. Every delivery
and drop (with its cause) is appended to ``network-events.jsonl`` in the run directory when there is one
(the configuration's ``run_dir``; by hand, ``--run-dir``, default ``$HARNESS_RUN_DIR``).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import IO

from harness.core import lifeline
from harness.core.errors import HarnessError, ScenarioError
from harness.net.model import NetworkKind, NetworkModel, StepResult, lookahead_ns
from harness.net.process_config import NetworkProcessConfig
from harness.wire import protocol as p
from harness.wire.client import ChannelClient, ChannelClosed

log = logging.getLogger(__name__)


def make_model(name: NetworkKind | str, seed: int, params: dict[str, object]) -> NetworkModel:
    if name == NetworkKind.BUILTIN:
        from harness.net.builtin import BuiltinRadio, RadioConfig

        return BuiltinRadio(RadioConfig.from_params(params), seed)
    if name == NetworkKind.NS3:
        from harness.net.ns3model import Ns3Config, Ns3Radio

        return Ns3Radio(Ns3Config.from_params(params), seed)
    raise ScenarioError(f"network model {name!r} is unknown: use 'builtin', 'ns3' or 'none'")


def _write_events(out: IO[str], result: StepResult) -> None:
    for d in result.deliveries:
        pk = d.packet
        out.write(
            json.dumps(
                {
                    "t_s": d.at_ns / 1e9,
                    "kind": "deliver",
                    "src": pk.src,
                    "dst": pk.dst,
                    "rssi_dbm": round(d.rssi_dbm, 1),
                }
            )
            + "\n"
        )
    for x in result.drops:
        out.write(
            json.dumps({"t_s": x.t_ns / 1e9, "kind": "drop", "src": x.packet.src, "dst": x.dst, "cause": x.cause.value})
            + "\n"
        )


def serve(client: ChannelClient, model: NetworkModel, events: IO[str] | None = None) -> int:
    """Answer phase 1 until the run ends; returns the number of intervals simulated."""
    steps = 0
    while True:
        try:
            msgs = client.recv()
        except ChannelClosed:
            return steps
        for msg in msgs:
            if isinstance(msg, p.BeginTick1):
                positions = {vp.vehicle: vp.ned_m for vp in msg.positions}
                result = model.step(msg.t_ns, msg.period_ns, positions, msg.packets)
                by_dst: dict[int, list[p.Deliver]] = {}
                for d in result.deliveries:  # in arrival order, grouped by receiver: one frame each
                    by_dst.setdefault(d.packet.dst, []).append(p.Deliver(d.at_ns, d.packet, d.rssi_dbm))
                out: list[p.Message] = [p.DeliverMany(dst, tuple(ds)) for dst, ds in by_dst.items()]
                out.append(p.EndTick1(msg.t_ns, lookahead_ns(model, msg.t_ns, msg.period_ns)))
                client.send_many(out)
                if events is not None:
                    _write_events(events, result)
                    events.flush()  # whole steps reach the file as they happen: the live 3D view reads it
                steps += 1
            elif isinstance(msg, p.Bye):
                return steps
            elif isinstance(msg, p.Error):
                raise HarnessError(f"the channel ended the run: {msg.message}")


def main(argv: Sequence[str] | None = None) -> int:
    lifeline.hold_on()  # started by a run (Children): die with it, before anything else
    ap = argparse.ArgumentParser(prog="python -m harness.net.subscriber", description=__doc__)
    ap.add_argument("--config", type=Path, default=None, help="the whole configuration (harness run's network.json)")
    ap.add_argument("--address", default=None)
    ap.add_argument("--model", default="builtin")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--params", default="{}", help="JSON object of model parameters")
    ap.add_argument("--name", default="network")
    ap.add_argument("--run-dir", default=os.environ.get("HARNESS_RUN_DIR"), help="default $HARNESS_RUN_DIR")
    a = ap.parse_args(argv)
    if a.config is None and a.address is None:
        ap.error("--address (or --config) is required")
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        cfg = NetworkProcessConfig.read(a.config) if a.config is not None else _from_flags(a)
        model = make_model(cfg.model, cfg.seed, cfg.params)
        client = ChannelClient.connect(cfg.address, p.PeerKind.TYPE1, cfg.name)
    except HarnessError as exc:
        log.error("%s", exc)
        return 2
    events = (Path(cfg.run_dir) / "network-events.jsonl").open("a") if cfg.run_dir else None
    try:
        serve(client, model, events)
    except HarnessError as exc:
        log.error("%s", exc)
        return 1
    finally:
        client.close()
        if events is not None:
            events.close()
    return 0


def _from_flags(a: argparse.Namespace) -> NetworkProcessConfig:
    """The configuration of a process started by hand, as ``--config`` would give it."""
    try:
        params = json.loads(a.params)
    except json.JSONDecodeError as exc:
        raise ScenarioError(f"--params is not JSON: {exc}") from None
    if not isinstance(params, dict):
        raise ScenarioError(f"--params must be a JSON object, got {a.params!r}")
    if a.model not in set(NetworkKind):
        raise ScenarioError(f"network model {a.model!r} is unknown: use 'builtin', 'ns3' or 'none'")
    return NetworkProcessConfig(
        address=a.address, model=NetworkKind(a.model), seed=a.seed, params=params, name=a.name, run_dir=a.run_dir
    )


if __name__ == "__main__":
    raise SystemExit(main())
