"""Acceptance (issue 6): the ns-3 model (extra uav-harness[ns3], installed by CI)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from harness.pytest_plugin import RunRecord
from harness.wire.protocol import BROADCAST, Packet

ns3model = pytest.importorskip("harness.net.ns3model")
pytest.importorskip("ns")
PERIOD = 20_000_000
CHATTER = Path(__file__).parent / "scripts" / "chatter.py"


def test_near_pair_delivers_far_pair_nothing_and_moving_in_restores_delivery() -> None:
    radio = ns3model.Ns3Radio(ns3model.Ns3Config(max_vehicles=3), seed=1)
    pos = {0: (0.0, 0.0, -10.0), 1: (50.0, 0.0, -10.0), 2: (500.0, 0.0, -10.0)}
    got: dict[int, list[int]] = {1: [], 2: []}
    for k in range(150):
        if k == 100:
            pos[2] = (0.0, 40.0, -10.0)  # flies into range
        res = radio.step(k * PERIOD, PERIOD, pos, [Packet(k * PERIOD, 0, BROADCAST, 0, k, b"x" * 100)])
        for d in res.deliveries:
            assert d.packet.src == 0 and k * PERIOD <= d.at_ns <= (k + 1) * PERIOD
            got[d.packet.dst].append(k)
    near = len(got[1]) / 150
    print(f"FIGURE ns3 near {near:.3f} far {sum(1 for k in got[2] if k < 100)} after-move {len(got[2])}/50")
    assert near >= 0.95
    assert [k for k in got[2] if k < 100] == []
    assert got[2] and got[2][0] == 100 and len(got[2]) >= 0.95 * 50


@pytest.mark.sim
def test_missions_talk_through_ns3(harness_run: Callable[..., RunRecord]) -> None:
    run = harness_run(mission=CHATTER, vehicles=2, extra=["--network", "ns3"])
    assert run.ok, run.message
    for v in range(2):
        heard = json.loads(run.mission_output(v))
        assert len(heard) == 10 and {h["src"] for h in heard} == {1 - v}
        assert all(h["sent_s"] < h["at_s"] <= h["sent_s"] + 0.02 for h in heard)
