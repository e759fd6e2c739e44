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
from harness.fdm.physics import Physics
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


def serve(
    client: ChannelClient,
    autopilots: dict[int, Autopilot],
    stop: threading.Event | None = None,
    physics: Physics | None = None,
) -> int:
    """Answer ticks until the channel says BYE or closes; returns the number of ticks answered.

    With ``physics`` (simulating exactly the vehicles of ``autopilots``) this host is a worker of
    ``harness run --workers``: BEGIN-TICK-AC carry no sensor frame; once a tick's are all in, each autopilot
    steps with its own vehicle's frame, the END-TICK-AC go out with that frame's ground truth, and only
    then the physics steps with the motors (the root records, the missions run and the network carries
    their packets meanwhile), so the next tick's frames are ready when its BEGIN-TICK-AC arrive.
    """
    if physics is not None and sorted(physics.owned) != sorted(autopilots):
        raise ScenarioError(
            f"{client.name}: physics of vehicles {list(physics.owned)}, autopilots of {sorted(autopilots)}"
        )
    ticks = 0
    pending: list[p.BeginTickAC] = []
    while stop is None or not stop.is_set():
        try:
            msgs = client.recv()
        except ChannelClosed:
            return ticks
        out: list[p.Message] = []
        for msg in msgs:
            if type(msg) is p.BeginTickAC:
                if physics is None:
                    out.append(_answer(client, autopilots, msg))
                    ticks += 1
                    continue
                pending.append(msg)
                if len(pending) == msg.count:
                    answers, motors = _worker_tick(client, autopilots, physics, pending)
                    client.send_many(answers)
                    physics.step(motors)
                    ticks += len(pending)
                    pending = []
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


def _autopilot_of(client: ChannelClient, autopilots: dict[int, Autopilot], vehicle: int) -> Autopilot:
    ap = autopilots.get(vehicle)
    if ap is None:
        raise SimulationError(
            f"{client.name}: the channel sent a tick for vehicle {vehicle}, but this host flies {sorted(autopilots)}"
        )
    return ap


def _answer(client: ChannelClient, autopilots: dict[int, Autopilot], msg: p.BeginTickAC) -> p.EndTickAC:
    """One autopilot's step with the sensor frame its BEGIN-TICK-AC brought."""
    ap = _autopilot_of(client, autopilots, msg.vehicle)
    try:
        frame = decode_frame(msg.frame)
    except (msgspec.DecodeError, msgspec.ValidationError) as exc:
        raise SimulationError(f"{client.name}: bad sensor frame for vehicle {msg.vehicle}: {exc}") from None
    return p.EndTickAC(msg.t_ns, msg.vehicle, ap.step(frame), p.pack_status(*ap.tick_status()))


def _worker_tick(
    client: ChannelClient, autopilots: dict[int, Autopilot], physics: Physics, begin: list[p.BeginTickAC]
) -> tuple[list[p.Message], list[tuple[float, float, float, float]]]:
    """A tick of a host that steps its vehicles' physics too: the answers (sent before the physics steps)
    and the motor commands, in the physics' order."""
    t_ns = begin[0].t_ns
    if t_ns != physics.t_ns or len(begin) != len(physics.owned) or any(m.t_ns != t_ns for m in begin):
        raise SimulationError(
            f"{client.name}: the channel sent {len(begin)} BEGIN-TICK-AC for t={t_ns} ns, but this host "
            f"simulates vehicles {list(physics.owned)} at t={physics.t_ns} ns"
        )
    frames = {f.vehicle: f for f in physics.frames()}
    motors: dict[int, tuple[float, float, float, float]] = {}
    out: list[p.Message] = []
    for msg in begin:
        ap = _autopilot_of(client, autopilots, msg.vehicle)
        frame = frames[msg.vehicle]
        cmd = motors[msg.vehicle] = ap.step(frame)
        tr = frame.truth
        truth = p.pack_truth(
            tr.pos_ned_m, tr.vel_ned_m_s, tr.quat, tr.lat_deg, tr.lon_deg, tr.alt_amsl_m, tr.on_ground, tr.crashed
        )
        out.append(p.EndTickAC(t_ns, msg.vehicle, cmd, p.pack_status(*ap.tick_status()), truth))
    return out, [motors[v] for v in physics.owned]


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
    physics: Physics | None = None,
) -> dict[int, Autopilot]:
    """Fly ``vehicles`` in lockstep with the channel at ``address`` until the run ends.

    ``config_for(v)`` gives each vehicle's configuration; ``attach(ap)`` plugs in the MAVLink side;
    ``physics`` (of exactly ``vehicles``): this host steps their physics too (:func:`serve`).
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
            serve(client, aps, stop, physics)
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
