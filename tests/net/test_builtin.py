"""Acceptance of the built-in radio model (issue 6): statistics, timing, queues, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest

from harness.net.builtin import C_M_S, BuiltinRadio, RadioConfig
from harness.net.model import DropCause
from harness.wire.protocol import BROADCAST, Packet

PERIOD = 20_000_000


def one_by_one(radio: BuiltinRadio, distance_m: float, n: int, payload: int = 100) -> int:
    pos = {0: (0.0, 0.0, -10.0), 1: (distance_m, 0.0, -10.0)}
    delivered = 0
    for k in range(n):
        res = radio.step(k * PERIOD, PERIOD, pos, [Packet(k * PERIOD, 0, 1, 0, k, b"x" * payload)])
        delivered += len(res.deliveries)
    return delivered


@pytest.mark.parametrize("distance_m", [150.0, 300.0, 330.0, 360.0, 450.0])
def test_delivery_ratio_versus_distance_matches_the_model(distance_m: float) -> None:
    cfg = RadioConfig()
    n = 10_000
    measured = one_by_one(BuiltinRadio(cfg, seed=3), distance_m, n) / n
    # expected: mean over the shadowing distribution of 1 - PER(SNR)
    nodes, weights = np.polynomial.hermite_e.hermegauss(60)
    mean_rx = cfg.mean_rx_dbm(distance_m)
    expected = sum(
        w * (1.0 - cfg.per(mean_rx - cfg.shadowing_sigma_db * x - cfg.noise_floor_dbm, 100))
        for x, w in zip(nodes, weights, strict=True)
    ) / math.sqrt(2 * math.pi)
    tolerance = 4 * math.sqrt(max(expected * (1 - expected), 1e-4) / n)
    print(f"FIGURE delivery d={distance_m} measured={measured:.4f} expected={expected:.4f}")
    assert measured == pytest.approx(expected, abs=tolerance)


def test_latency_is_transmission_plus_propagation() -> None:
    cfg = RadioConfig(shadowing_sigma_db=0.0)
    radio = BuiltinRadio(cfg)
    d = 120.0
    res = radio.step(0, PERIOD, {0: (0, 0, 0), 1: (d, 0, 0)}, [Packet(0, 0, 1, 7, 0, b"y" * 200)])
    (delivery,) = res.deliveries
    expected = round(cfg.airtime_s(200) * 1e9) + round(d / C_M_S * 1e9)
    assert delivery.at_ns == expected
    assert delivery.packet.dst == 1 and delivery.packet.port == 7


def test_queue_overflow_drops_are_counted() -> None:
    radio = BuiltinRadio(RadioConfig(queue_limit=10, shadowing_sigma_db=0.0))
    packets = [Packet(0, 0, 1, 0, i, b"z" * 1000) for i in range(100)]
    res = radio.step(0, 1_000_000_000, {0: (0, 0, 0), 1: (10, 0, 0)}, packets)
    queue_drops = [d for d in res.drops if d.cause is DropCause.QUEUE]
    # the first goes on the air at once, the next 10 wait in the queue, the other 89 are dropped
    assert len(queue_drops) == radio.dropped[DropCause.QUEUE] == 89
    assert len(res.deliveries) == 11
    times = [d.at_ns for d in res.deliveries]
    assert times == sorted(times) and len(set(times)) == 11  # one at a time on the air


def test_same_seed_same_drops_and_broadcast_expansion() -> None:
    def run(seed: int) -> list[tuple[int, int, str]]:
        radio = BuiltinRadio(seed=seed)
        pos = {i: (90.0 * i, 0.0, -10.0) for i in range(6)}
        out = []
        for k in range(200):
            res = radio.step(k * PERIOD, PERIOD, pos, [Packet(k * PERIOD, k % 6, BROADCAST, 0, k, b"b" * 64)])
            out += [(d.packet.seq, d.dst, d.cause.value) for d in res.drops]
            assert all(d.packet.dst != d.packet.src for d in res.deliveries)
        return out

    a, b, c = run(5), run(5), run(6)
    assert a and a == b and a != c
    assert {cause for _, _, cause in a} <= {"error", "range", "collision"}


def test_range_cut_off_and_unknown_receiver() -> None:
    radio = BuiltinRadio(RadioConfig(max_range_m=50.0))
    res = radio.step(0, PERIOD, {0: (0, 0, 0), 1: (60, 0, 0)}, [Packet(0, 0, 1, 0, 0, b""), Packet(0, 0, 9, 0, 1, b"")])
    assert [d.cause for d in res.drops] == [DropCause.RANGE, DropCause.RANGE]


def test_hidden_terminals_collide_but_neighbours_take_turns() -> None:
    # 0 and 2 cannot hear each other (900 m apart) but both reach 1 in the middle: they overlap at 1
    cfg = RadioConfig(shadowing_sigma_db=0.0, tx_power_dbm=30.0)
    radio = BuiltinRadio(cfg)
    pos = {0: (0.0, 0.0, 0.0), 1: (450.0, 0.0, 0.0), 2: (900.0, 0.0, 0.0)}
    assert cfg.mean_rx_dbm(900.0) < cfg.carrier_sense_dbm < cfg.mean_rx_dbm(450.0)
    res = radio.step(0, PERIOD, pos, [Packet(0, 0, 1, 0, 0, b"a" * 100), Packet(0, 2, 1, 0, 1, b"c" * 100)])
    assert {d.cause for d in res.drops} == {DropCause.COLLISION}
    # neighbours that hear each other defer (CSMA): both arrive
    near = {0: (0.0, 0.0, 0.0), 1: (20.0, 0.0, 0.0), 2: (40.0, 0.0, 0.0)}
    res = BuiltinRadio(cfg).step(
        0, PERIOD, near, [Packet(0, 0, 1, 0, 0, b"a" * 100), Packet(0, 2, 1, 0, 1, b"c" * 100)]
    )
    assert len(res.deliveries) == 2 and not res.drops
