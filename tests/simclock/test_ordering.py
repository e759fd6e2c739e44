"""Acceptance: ordering of the two-phase tick, single channel and a tree, over real processes."""

from __future__ import annotations

import json
from typing import Any

import pytest

from harness.channel import Channel, ChannelConfig
from harness.channel.drivers import fake_position, run_fake_physics
from tests.helpers import wait_until

from .conftest import Procs, load

TICKS = 300


def check_invariants(
    type0: list[list[dict[str, Any]]],
    type1: list[list[dict[str, Any]]],
    physics: Any,
    vehicles: int,
    strict: bool = True,
) -> None:
    work0: dict[int, list[dict[str, Any]]] = {}
    work1: dict[int, list[dict[str, Any]]] = {}
    for trace in type0:
        for ev in trace:
            if ev["ev"] == "work0":
                work0.setdefault(ev["tick"], []).append(ev)
    for trace in type1:
        for ev in trace:
            if ev["ev"] == "work1":
                work1.setdefault(ev["tick"], []).append(ev)
    eta = {ev["tick"]: ev for ev in physics.trace}
    assert set(work0) == set(work1) == set(range(TICKS)), "every tick ran both phases"
    for k in range(TICKS):
        # every type-0 and every type-1 subscriber ran in this tick
        assert len(work0[k]) == len(type0) and len(work1[k]) == len(type1)
        # phase 1 starts after every phase-0 work of the tick has ended ...
        assert min(w["start"] for w in work1[k]) > max(w["end"] for w in work0[k])
        # ... and the next phase 0 starts after every phase-1 work has ended: no overlap ever
        if k + 1 < TICKS:
            assert min(w["start"] for w in work0[k + 1]) > max(w["end"] for w in work1[k])
        if strict:  # the paper's order: physics gets END-TICK-AC only after every END-TICK-1 of the tick
            assert eta[k]["wall"] > max(w["end"] for w in work1[k])
        else:  # overlap_phase1: physics goes on once phase 0 is over, beside phase 1 (checked above)
            assert eta[k]["wall"] > max(w["end"] for w in work0[k])
        # BEGIN-TICK-1 carries the positions of the same tick
        for w in work1[k]:
            assert w["positions"] == [[v, list(fake_position(v, k))] for v in range(vehicles)]
            # a packet enqueued in tick k's phase 0 is offered in tick k's phase 1
            ticks_of_packets = sorted(json.loads(pk)["tick"] for pk in w["packets"])
            assert ticks_of_packets == [k] * len(ticks_of_packets)
            assert len(ticks_of_packets) == sum(1 for _ in type0)


@pytest.mark.parametrize("strict", [True, False], ids=["paper-order", "overlap-phase1"])
def test_ordering_single_channel(procs: Procs, strict: bool) -> None:
    ch = Channel(ChannelConfig(stall_timeout_s=20, phase_every=1, overlap_phase1=not strict)).start()
    try:
        procs.driver("autopilot", ch.address, "--vehicle", "0", "--vehicle", "1", "--vehicle", "2")
        t0 = [
            procs.driver(
                "type0",
                ch.address,
                "--vehicle",
                str(i % 3),
                "--enqueue-to",
                str((i + 1) % 3),
                "--work-us",
                "300",
                name=f"m{i}",
            )[1]
            for i in range(4)
        ]
        t1 = [procs.driver("type1", ch.address, "--work-us", "300", name=f"net{i}")[1] for i in range(2)]
        wait_until(lambda: len(ch.subscribers()) == 7, what="7 subscribers")
        stats = run_fake_physics(ch.address, 3, TICKS)
        for p in procs.procs:
            p.wait(10)
        check_invariants([load(t) for t in t0], [load(t) for t in t1], stats, 3, strict)
        assert ch.faults == [] and ch.failure is None
    finally:
        ch.stop()


def test_ordering_tree_of_channels(procs: Procs) -> None:
    """Vehicles split over a root and two child channels (separate processes, TCP)."""
    root = Channel(ChannelConfig(stall_timeout_s=20, phase_every=1)).start()
    try:
        _, child_a = procs.channel("--parent", root.address, "--name", "child-a")
        _, child_b = procs.channel("--parent", root.address, "--name", "child-b")
        procs.driver("autopilot", root.address, "--vehicle", "0", name="ap-root")
        procs.driver("autopilot", child_a, "--vehicle", "1", name="ap-a")
        procs.driver("autopilot", child_b, "--vehicle", "2", name="ap-b")
        places = [root.address, child_a, child_b, child_b]
        t0 = [
            procs.driver(
                "type0",
                places[i],
                "--vehicle",
                str(i % 3),
                "--enqueue-to",
                str((i + 1) % 3),
                "--work-us",
                "300",
                name=f"m{i}",
            )[1]
            for i in range(4)
        ]
        t1 = [
            procs.driver("type1", addr, "--work-us", "300", name=f"net{i}")[1]
            for i, addr in enumerate([root.address, child_a])
        ]
        # 2 children + ap + m0 + net0 at the root; ap + m1 + net1 below child-a; ap + m2 + m3 below child-b
        wait_until(lambda: root.tree_size() == 5 + 3 + 3, what="every subscriber of the tree")
        stats = run_fake_physics(root.address, 3, TICKS)
        for p in procs.procs:
            p.wait(10)
        type0 = [load(t) for t in t0]
        check_invariants(type0, [load(t) for t in t1], stats, 3, strict=False)
        # packets cross the tree: every mission got DELIVERs of packets addressed to its vehicle
        delivered = [sum(1 for ev in tr if ev["ev"] == "deliver") for tr in type0]
        assert all(n > 0 for n in delivered), delivered
        assert root.failure is None and root.faults == []
    finally:
        root.stop()
