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
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol

import msgspec

from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.autopilot.events import VehicleEvent, encode_events
from harness.core.errors import ScenarioError, SimulationError
from harness.fdm.environment import WorldChange
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
            if self.ap.telemetry.arming_check() == "" and self.ap.action.arm().ok:
                self.ap.action.takeoff(self.alt_m)
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
    while stop is None or not stop.is_set():
        try:
            msgs = client.recv()
        except ChannelClosed:
            return ticks
        out: list[p.Message] = []
        for msg in msgs:
            if type(msg) is p.BeginTickAC:
                out.append(_answer(client, autopilots, msg))
                ticks += 1
            elif _ends(client, msg):
                if out:
                    client.send_many(out)
                return ticks
        if out:
            client.send_many(out)
    return ticks


def _ends(client: ChannelClient, msg: p.Message) -> bool:
    """BYE ends the host; a fatal ERROR fails it; anything else is ignored here."""
    if isinstance(msg, p.Bye):
        return True
    if isinstance(msg, p.Error):
        if msg.fatal:
            raise SimulationError(f"{client.name}: the channel failed the run: {msg.message}")
        log.warning("%s: channel error: %s", client.name, msg.message)
    return False


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
    motors = ap.step(frame)
    events = encode_events(ap.take_events())
    return p.EndTickAC(msg.t_ns, msg.vehicle, motors, p.pack_status(*ap.tick_status()), events=events)


class _Inbox:
    """The messages of one connection, one at a time; None once the channel has ended (BYE, closed)."""

    def __init__(self, client: ChannelClient) -> None:
        self.client = client
        self._queue: deque[p.Message] = deque()

    def next(self) -> p.Message | None:
        while not self._queue:
            try:
                self._queue.extend(self.client.recv())
            except ChannelClosed:
                return None
        msg = self._queue.popleft()
        return None if _ends(self.client, msg) else msg


def serve_worker(
    client: ChannelClient,
    clock: ChannelClient,
    autopilots: dict[int, Autopilot],
    physics: Physics,
    stop: threading.Event | None = None,
    mavlink_sent: Mapping[int, Callable[[], bool]] | None = None,
) -> int:
    """Fly ``autopilots`` and step their ``physics`` (a worker of ``harness run --workers``) until the run
    ends; returns the number of ticks stepped.

    The channel asks this host only at the ticks with phases (BEGIN-TICK-AC without a sensor frame); in
    between, nothing outside can reach its vehicles (missions run only in phase 0), so it runs on alone:
    from the end of one phase 0 — BEGIN-TICK-1 on ``clock``, a type-1 connection that answers at once —
    through every tick up to the next phase tick, whose autopilot step is ready when that BEGIN-TICK-AC
    arrives. The END-TICK-AC then carry every tick since the last (truth, motors, status), and the
    physics steps once they are sent, while the root runs the phases. With ``mavlink_sent`` (by vehicle, its
    MAVLink server's ``sent_to_missions``) each END-TICK-AC says whether the vehicle sent its mission MAVLink since
    the last.
    """
    if sorted(physics.owned) != sorted(autopilots):
        raise ScenarioError(
            f"{client.name}: physics of vehicles {list(physics.owned)}, autopilots of {sorted(autopilots)}"
        )
    owned = physics.owned
    ticks, next_phase_ns = 0, 0
    records: dict[int, list[bytes]] = {v: [] for v in owned}
    changes: dict[int, list[VehicleEvent]] = {v: [] for v in owned}
    """The vehicles' events since the last END-TICK-AC (world changes applied here), for the recording."""
    sent = dict(mavlink_sent or {})
    inbox, phases = _Inbox(client), _Inbox(clock)
    while stop is None or not stop.is_set():
        while True:  # every tick up to the next phase tick, the autopilots of that one included
            answers = _step_autopilots(autopilots, physics, records, changes)
            ticks += 1
            if physics.t_ns >= next_phase_ns:
                break
            physics.step([m for m, _ in answers])
        begin: list[p.BeginTickAC] = []
        while not begin or len(begin) < begin[0].count:
            msg = inbox.next()
            if msg is None:
                return ticks
            if type(msg) is p.BeginTickAC:
                begin.append(msg)
        if {m.t_ns for m in begin} != {physics.t_ns} or sorted(m.vehicle for m in begin) != sorted(owned):
            raise SimulationError(
                f"{client.name}: the channel asked for vehicles {sorted(m.vehicle for m in begin)} at "
                f"t={begin[0].t_ns} ns; this host simulates {list(owned)} and is at t={physics.t_ns} ns"
            )
        t_ns = physics.t_ns
        out: list[p.Message] = []
        for v, (m, status) in zip(owned, answers, strict=True):
            told = sent.get(v)
            mavlink = p.MAVLINK_UNKNOWN if told is None else 1 if told() else 0
            out.append(p.EndTickAC(t_ns, v, m, status, b"".join(records[v]), mavlink, encode_events(changes[v])))
            records[v].clear()
            changes[v].clear()
        client.send_many(out)
        physics.step([m for m, _ in answers])
        while True:  # phase 0 of this tick ends when its phase 1 begins
            msg = phases.next()
            if msg is None:
                return ticks
            if isinstance(msg, p.BeginTick1) and msg.t_ns == t_ns:
                clock.send(p.EndTick1(t_ns))
                next_phase_ns = t_ns + msg.period_ns
                break
    return ticks


def _step_autopilots(
    autopilots: dict[int, Autopilot],
    physics: Physics,
    records: dict[int, list[bytes]],
    changes: dict[int, list[VehicleEvent]],
) -> list[tuple[tuple[float, float, float, float], int]]:
    """Every autopilot's step with its own vehicle's frame at this tick (motors, status), recorded with
    the frame's truth; a change of a vehicle's world applied to the physics before its next step."""
    out = []
    for frame in physics.frames():
        ap = autopilots[frame.vehicle]
        motors = ap.step(frame)
        status = p.pack_status(*ap.tick_status())
        records[frame.vehicle].append(p.pack_tick(frame.truth, motors, status))
        out.append((motors, status))
        if ap.world.pending or ap.camera.recorded:
            for event in ap.take_events():
                if isinstance(event, WorldChange):
                    physics.apply(frame.vehicle, event)
                changes[frame.vehicle].append(event)
    return out


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
    mavlink_sent: Mapping[int, Callable[[], bool]] | None = None,
) -> dict[int, Autopilot]:
    """Fly ``vehicles`` in lockstep with the channel at ``address`` until the run ends.

    ``config_for(v)`` gives each vehicle's configuration; ``attach(ap)`` plugs in the MAVLink side;
    ``physics`` (of exactly ``vehicles``): this host steps their physics too (:func:`serve_worker`, which tells
    the channel from ``mavlink_sent``, by vehicle, when it sent its mission MAVLink).
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
            if physics is None:
                serve(client, aps, stop)
            else:
                with ChannelClient.connect(address, p.PeerKind.TYPE1, f"{label}:clock", secret=secret) as clock:
                    serve_worker(client, clock, aps, physics, stop, mavlink_sent)
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
