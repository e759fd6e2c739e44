"""Test drivers: a minimal fake physics, fake autopilot and fake type-0/type-1 subscribers.

They speak the real protocol over real sockets, so the lockstep core is tested and measured on its
own, without JSBSim or an autopilot. Each records a trace of what it saw and when (wall-clock
``CLOCK_MONOTONIC`` nanoseconds, comparable across processes on one machine) and writes it as JSON.

Run one as a process::

    python -m harness.channel.drivers physics   --address tcp://127.0.0.1:5760 --vehicles 3 --ticks 100
    python -m harness.channel.drivers autopilot --address ... --vehicle 0 --vehicle 1
    python -m harness.channel.drivers type0     --address ... --name m0 --vehicle 0 --work-us 200
    python -m harness.channel.drivers type1     --address ... --name net --work-us 200
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from harness.channel import Channel
from harness.core.clock import NS_PER_S, real_monotonic_ns, real_sleep
from harness.wire import protocol as p
from harness.wire.client import ChannelClient, ChannelClosed

log = logging.getLogger(__name__)

Event = dict[str, Any]
_ready_file: Path | None = None


def _connected(client: ChannelClient) -> ChannelClient:
    if _ready_file is not None:
        _ready_file.touch()
    return client


def _busy(work_us: float) -> None:
    """Occupy the CPU for ``work_us`` microseconds (a subscriber doing real work)."""
    if work_us <= 0:
        return
    end = real_monotonic_ns() + int(work_us * 1000)
    while real_monotonic_ns() < end:
        pass


def fake_position(vehicle: int, tick: int) -> p.Vec3:
    """Where the fake physics says ``vehicle`` is at ``tick``: a known function, checkable by type 1."""
    return (10.0 * vehicle + 0.01 * tick, -2.0 * vehicle, -10.0)


@dataclass
class PhysicsStats:
    ticks: int = 0
    tick_wall_ns: list[int] = field(default_factory=list)
    trace: list[Event] = field(default_factory=list)


def run_fake_physics(
    address: str,
    vehicles: int,
    ticks: int,
    *,
    tick_hz: float = 250.0,
    speed: float | None = None,
    name: str = "physics",
    trace: bool = True,
) -> PhysicsStats:
    """Emit BEGIN-TICK-AC for every vehicle, wait for every END-TICK-AC, ``ticks`` times.

    ``speed`` paces sim time at that multiple of wall time (None: as fast as possible).
    """
    tick_ns = round(NS_PER_S / tick_hz)
    stats = PhysicsStats()
    client = ChannelClient.connect(address, p.PeerKind.PHYSICS, name, vehicles=tuple(range(vehicles)))
    start = real_monotonic_ns()
    try:
        for k in range(ticks):
            t_ns = k * tick_ns
            if speed is not None:
                due = start + int(t_ns / speed)
                lag = due - real_monotonic_ns()
                if lag > 0:
                    real_sleep(lag / NS_PER_S)
            sent = real_monotonic_ns()
            client.send_many([p.BeginTickAC(t_ns, k, v, vehicles, fake_position(v, k), b"") for v in range(vehicles)])
            got: dict[int, p.EndTickAC] = {}
            while len(got) < vehicles:
                for msg in client.recv():
                    if isinstance(msg, p.EndTickAC):
                        if msg.t_ns != t_ns:
                            raise AssertionError(f"END-TICK-AC for t={msg.t_ns}, expected {t_ns}")
                        got[msg.vehicle] = msg
                    elif isinstance(msg, p.Error):
                        raise ChannelClosed(f"channel failed the run: {msg.message}")
            done = real_monotonic_ns()
            stats.tick_wall_ns.append(done - sent)
            if trace:
                stats.trace.append({"ev": "eta_all", "tick": k, "wall": done, "sent": sent})
            stats.ticks += 1
    finally:
        client.close("end of run")
    return stats


def run_fake_physics_local(channel: Channel, vehicles: int, ticks: int, *, tick_hz: float = 250.0) -> PhysicsStats:
    """The same as :func:`run_fake_physics`, owning the root ``channel`` in this process."""
    tick_ns = round(NS_PER_S / tick_hz)
    stats = PhysicsStats()
    for k in range(ticks):
        t_ns = k * tick_ns
        sent = real_monotonic_ns()
        etas = channel.step([p.BeginTickAC(t_ns, k, v, vehicles, fake_position(v, k), b"") for v in range(vehicles)])
        if len(etas) != vehicles or any(e.t_ns != t_ns for e in etas):
            raise AssertionError(f"tick {k}: wrong END-TICK-AC {etas}")
        stats.tick_wall_ns.append(real_monotonic_ns() - sent)
        stats.ticks += 1
    return stats


def run_fake_autopilot(address: str, vehicles: Sequence[int], *, name: str = "autopilot") -> list[Event]:
    """Answer every BEGIN-TICK-AC with a hover command; return the trace."""
    events: list[Event] = []
    client = _connected(ChannelClient.connect(address, p.PeerKind.AUTOPILOT, name, vehicles=tuple(vehicles)))
    try:
        while True:
            out: list[p.Message] = []
            for msg in client.recv():
                if isinstance(msg, p.BeginTickAC):
                    out.append(p.EndTickAC(msg.t_ns, msg.vehicle, (0.5, 0.5, 0.5, 0.5)))
                    events.append({"ev": "bta", "tick": msg.tick, "vehicle": msg.vehicle, "wall": real_monotonic_ns()})
                elif isinstance(msg, p.Bye | p.Error):
                    return events
            if out:
                client.send_many(out)
    except ChannelClosed:
        return events
    finally:
        client.close()


def run_fake_type0(
    address: str,
    *,
    name: str = "type0",
    vehicle: int = -1,
    work_us: float = 0.0,
    enqueue_to: int | None = None,
    stall_at_tick: int | None = None,
) -> list[Event]:
    """A type-0 subscriber: on each BEGIN-TICK-0, work, optionally ENQUEUE a packet, END-TICK-0."""
    events: list[Event] = []
    client = _connected(ChannelClient.connect(address, p.PeerKind.TYPE0, name, vehicle=vehicle))
    seq = 0
    try:
        while True:
            for msg in client.recv():
                if isinstance(msg, p.BeginTick0):
                    if stall_at_tick is not None and msg.tick >= stall_at_tick:
                        real_sleep(3600)
                    start = real_monotonic_ns()
                    _busy(work_us)
                    out: list[p.Message] = []
                    if enqueue_to is not None:
                        payload = json.dumps({"tick": msg.tick, "from": name}).encode()
                        out.append(p.Enqueue(p.Packet(msg.t_ns, vehicle, enqueue_to, 0, seq, payload)))
                        seq += 1
                    end = real_monotonic_ns()
                    out.append(p.EndTick0(msg.t_ns))
                    client.send_many(out)
                    events.append({"ev": "work0", "tick": msg.tick, "t_ns": msg.t_ns, "start": start, "end": end})
                elif isinstance(msg, p.Deliver):
                    events.append(
                        {"ev": "deliver", "wall": real_monotonic_ns(), "payload": msg.packet.payload.decode()}
                    )
                elif isinstance(msg, p.Bye | p.Error):
                    return events
    except ChannelClosed:
        return events
    finally:
        client.close()


def run_fake_type1(
    address: str, *, name: str = "type1", work_us: float = 0.0, deliver: bool = True, never_answer: bool = False
) -> list[Event]:
    """A type-1 subscriber: on each BEGIN-TICK-1, record positions and packets, deliver, END-TICK-1."""
    events: list[Event] = []
    client = _connected(ChannelClient.connect(address, p.PeerKind.TYPE1, name))
    try:
        while True:
            for msg in client.recv():
                if isinstance(msg, p.BeginTick1):
                    if never_answer:
                        continue
                    start = real_monotonic_ns()
                    _busy(work_us)
                    out: list[p.Message] = []
                    if deliver:
                        for pk in msg.packets:
                            out.append(p.Deliver(msg.t_ns + msg.period_ns // 2, pk))
                    end = real_monotonic_ns()
                    out.append(p.EndTick1(msg.t_ns))
                    client.send_many(out)
                    events.append(
                        {
                            "ev": "work1",
                            "tick": msg.tick,
                            "t_ns": msg.t_ns,
                            "start": start,
                            "end": end,
                            "positions": [[vp.vehicle, list(vp.ned_m)] for vp in msg.positions],
                            "packets": [pk.payload.decode(errors="replace") for pk in msg.packets],
                        }
                    )
                elif isinstance(msg, p.Bye | p.Error):
                    return events
    except ChannelClosed:
        return events
    finally:
        client.close()


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m harness.channel.drivers")
    ap.add_argument("role", choices=["physics", "autopilot", "type0", "type1"])
    ap.add_argument("--address", required=True)
    ap.add_argument("--name", default=None)
    ap.add_argument("--vehicles", type=int, default=1, help="physics: number of vehicles")
    ap.add_argument("--vehicle", type=int, action="append", default=[], help="autopilot/type0: vehicle(s)")
    ap.add_argument("--ticks", type=int, default=100)
    ap.add_argument("--tick-hz", type=float, default=250.0)
    ap.add_argument("--speed", type=float, default=None)
    ap.add_argument("--work-us", type=float, default=0.0)
    ap.add_argument("--enqueue-to", type=int, default=None)
    ap.add_argument("--stall-at-tick", type=int, default=None)
    ap.add_argument("--never-answer", action="store_true")
    ap.add_argument("--trace", type=Path, default=None, help="write the trace here as JSON")
    ap.add_argument("--ready", type=Path, default=None, help="create this file once subscribed")
    a = ap.parse_args(argv)
    global _ready_file
    _ready_file = a.ready
    logging.basicConfig(level=logging.WARNING)
    name = a.name or a.role
    result: Any
    if a.role == "physics":
        stats = run_fake_physics(a.address, a.vehicles, a.ticks, tick_hz=a.tick_hz, speed=a.speed, name=name)
        result = {"ticks": stats.ticks, "tick_wall_ns": stats.tick_wall_ns, "trace": stats.trace}
    elif a.role == "autopilot":
        result = run_fake_autopilot(a.address, a.vehicle or [0], name=name)
    elif a.role == "type0":
        result = run_fake_type0(
            a.address,
            name=name,
            vehicle=a.vehicle[0] if a.vehicle else -1,
            work_us=a.work_us,
            enqueue_to=a.enqueue_to,
            stall_at_tick=a.stall_at_tick,
        )
    else:
        result = run_fake_type1(a.address, name=name, work_us=a.work_us, never_answer=a.never_answer)
    if a.trace:
        a.trace.write_text(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
