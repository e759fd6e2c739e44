"""Lockstep host: runs the autopilots of one or more vehicles against a channel (thin shell).

For each BEGIN-TICK-AC it decodes the sensor frame, steps that vehicle's ``Autopilot`` and answers
END-TICK-AC with the motor commands; the answers to everything one ``recv`` returned go out in one write.

The MAVLink interface attaches through ``attach``: called once per vehicle with its ``Autopilot`` before
the first tick; whatever it returns is closed (``close()``) when the host stops. Example::

    run_autopilots(addr, [0, 1], attach=lambda ap: MavlinkServer(ap, ...).start())
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import msgspec

from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.core.errors import ScenarioError, SimulationError
from harness.fdm.frame import decode_frame
from harness.wire import protocol as p
from harness.wire.client import ChannelClient, ChannelClosed

log = logging.getLogger(__name__)


class Closeable(Protocol):
    def close(self) -> Any: ...


class AutoTakeoff:
    """An ``attach`` hook for benchmarks and debugging: arms and takes off as soon as the checks pass.

    It polls on the wall clock from its own thread, as a ground station would.
    """

    def __init__(self, ap: Autopilot, alt_m: float, poll_s: float = 0.05) -> None:
        self.ap = ap
        self.alt_m = alt_m
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._run, args=(poll_s,), name=f"auto-takeoff-{ap.vehicle}", daemon=True
        )
        self._thread.start()

    def _run(self, poll_s: float) -> None:
        while not self._stop.wait(poll_s):
            if self.ap.arming_check() == "" and self.ap.arm().ok:
                self.ap.takeoff(self.alt_m)
                return

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1.0)


def make_autopilots(
    vehicles: Sequence[int], config_for: Callable[[int], AutopilotConfig] | None = None
) -> dict[int, Autopilot]:
    if not vehicles:
        raise ScenarioError("run_autopilots: no vehicles given; pass the indices this host should fly")
    if len(set(vehicles)) != len(vehicles):
        raise ScenarioError(f"run_autopilots: vehicle indices repeat in {list(vehicles)}")
    return {v: Autopilot(config_for(v) if config_for else AutopilotConfig(vehicle=v)) for v in vehicles}


def serve(client: ChannelClient, autopilots: dict[int, Autopilot], stop: threading.Event | None = None) -> int:
    """Answer ticks until the channel says BYE or closes; returns the number of ticks answered."""
    ticks = 0
    BeginTickAC, EndTickAC = p.BeginTickAC, p.EndTickAC
    while stop is None or not stop.is_set():
        try:
            msgs = client.recv()
        except ChannelClosed:
            return ticks
        out: list[p.Message] = []
        for msg in msgs:
            if type(msg) is BeginTickAC:
                ap = autopilots.get(msg.vehicle)
                if ap is None:
                    raise SimulationError(
                        f"{client.name}: the channel sent a tick for vehicle {msg.vehicle}, "
                        f"but this host flies {sorted(autopilots)}"
                    )
                try:
                    frame = decode_frame(msg.frame)
                except (msgspec.DecodeError, msgspec.ValidationError) as exc:
                    raise SimulationError(f"{client.name}: bad sensor frame for vehicle {msg.vehicle}: {exc}") from None
                out.append(EndTickAC(msg.t_ns, msg.vehicle, ap.step(frame), p.pack_status(*ap.tick_status())))
                ticks += 1
            elif isinstance(msg, p.Bye):
                if out:
                    client.send_many(out)
                return ticks
            elif isinstance(msg, p.Error):
                if msg.fatal:
                    raise SimulationError(f"{client.name}: the channel failed the run: {msg.message}")
                log.warning("%s: channel error: %s", client.name, msg.message)
        if out:
            client.send_many(out)
    return ticks


def run_autopilots(
    address: str,
    vehicles: Sequence[int],
    *,
    config_for: Callable[[int], AutopilotConfig] | None = None,
    attach: Callable[[Autopilot], Closeable | None] | None = None,
    name: str | None = None,
    secret: bytes | None = None,
    stop: threading.Event | None = None,
    autopilots: dict[int, Autopilot] | None = None,
) -> dict[int, Autopilot]:
    """Fly ``vehicles`` in lockstep with the channel at ``address`` until the run ends.

    ``config_for(v)`` gives each vehicle's configuration; ``attach(ap)`` plugs in the MAVLink side.
    Returns the autopilots (their final state is readable after the run).
    """
    aps = autopilots if autopilots is not None else make_autopilots(vehicles, config_for)
    attached: list[Closeable] = []
    try:
        if attach is not None:
            for v in vehicles:
                handle = attach(aps[v])
                if handle is not None:
                    attached.append(handle)
        label = name or "autopilot-" + "-".join(str(v) for v in vehicles)
        client = ChannelClient.connect(address, p.PeerKind.AUTOPILOT, label, vehicles=tuple(vehicles), secret=secret)
        try:
            serve(client, aps, stop)
        finally:
            client.close("autopilot host stopping")
    finally:
        for h in attached:
            with contextlib.suppress(Exception):
                h.close()
    return aps


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m harness.autopilot.host --address tcp://… --vehicles 0,1`` (one SITL-like process)."""
    import argparse

    ap = argparse.ArgumentParser(prog="harness-autopilot", description=main.__doc__)
    ap.add_argument("--address", required=True, help="channel address, e.g. tcp://127.0.0.1:5760")
    ap.add_argument("--vehicles", required=True, help="comma-separated vehicle indices this process flies")
    ap.add_argument("--name", default=None)
    ap.add_argument("--ground-truth", action="store_true", help="debug: estimator replaced by ground truth")
    ap.add_argument("--takeoff-alt", type=float, default=None, help="arm and take off to this height when ready")
    args = ap.parse_args(argv)
    try:
        vehicles = [int(v) for v in args.vehicles.split(",") if v.strip()]
    except ValueError:
        raise ScenarioError(f"--vehicles must be comma-separated integers, got {args.vehicles!r}") from None
    logging.basicConfig(level=logging.INFO)
    run_autopilots(
        args.address,
        vehicles,
        config_for=lambda v: AutopilotConfig(vehicle=v, use_ground_truth=args.ground_truth),
        attach=(lambda a: AutoTakeoff(a, args.takeoff_alt)) if args.takeoff_alt is not None else None,
        name=args.name,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
