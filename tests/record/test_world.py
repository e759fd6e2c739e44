"""``world.mcap``'s writer: the JSON of every topic, and its fast message path against mcap's own ``add_message``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from mcap.reader import make_reader

from harness.record.sample import VehicleSample
from harness.record.world import WorldRecorder, read_topics

EPOCH_NS = 1_700_000_000_000_000_000


def _sample(k: int, vehicle: int) -> VehicleSample:
    t_ns = k * 20_000_000
    motors = (0.5, math.nan, 0.25, 1.0) if k == 7 else (0.5 + vehicle / 100, 0.5, 0.25, k / 10_000)
    return VehicleSample(
        t_ns,
        vehicle,
        (1.0 + k / 3, -2.0 * vehicle, -k / 7),
        (0.9, 0.1, -0.2, 0.3),
        (0.1 * k, 0.2, -0.3),
        47.0 + k * 1e-7,
        8.0 - vehicle * 1e-6,
        488.5 + k / 9,
        motors,
        k < 3,
        False,
        0x10203,
    )


def _write(path: Path, public: bool, ticks: int, vehicles: int) -> WorldRecorder:
    rec = WorldRecorder(path, EPOCH_NS, vehicles)
    if public:
        rec._add = rec._add_message  # mcap's Writer.add_message for every message
        rec._add_vehicle = rec._add_vehicle_messages
        rec._before_finish = None  # and its own chunk indexes and message indexes
    for k in range(ticks):
        for v in range(vehicles):
            rec.vehicle(_sample(k, v))
        rec.tick(k * 20_000_000, 5 * k, 0.01 * k, 37.5)
        if k % 500 == 250:
            rec.event(k * 20_000_000, "paused", {"k": k})
            rec.flush()  # a chunk ended by the run's periodic flush, not by its size
    rec.close()
    return rec


@pytest.mark.parametrize(("vehicles", "ticks", "chunks"), [(3, 1500, 40), (60, 300, 80)])
def test_the_fast_path_writes_the_same_file_as_mcaps_add_message(
    tmp_path: Path, vehicles: int, ticks: int, chunks: int
) -> None:
    """Thousands of messages over dozens of 64 KiB chunks and flushes, a few topics (many messages per chunk
    and topic) or a swarm's (one or two): byte for byte the file mcap's own ``Writer.add_message`` writes
    (records, chunk boundaries, message indexes, statistics, summary)."""
    fast = _write(tmp_path / "fast.mcap", public=False, ticks=ticks, vehicles=vehicles)
    assert fast._add != fast._add_message, "this mcap's writer is not the one the fast path knows"
    assert fast._add_vehicle != fast._add_vehicle_messages
    _write(tmp_path / "public.mcap", public=True, ticks=ticks, vehicles=vehicles)
    data = (tmp_path / "fast.mcap").read_bytes()
    assert data == (tmp_path / "public.mcap").read_bytes()
    with (tmp_path / "fast.mcap").open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == ticks * vehicles * 3 + ticks + (ticks + 249) // 500
        assert len(summary.chunk_indexes) > chunks
        last = vehicles - 1
        times = [m.log_time for _, _, m in reader.iter_messages(topics=[f"/vehicle/{last}/state"])]
        assert times == [EPOCH_NS + k * 20_000_000 for k in range(ticks)]


def test_each_topic_holds_the_foxglove_and_harness_json(tmp_path: Path) -> None:
    _write(tmp_path / "world.mcap", public=False, ticks=10, vehicles=2)
    topics = read_topics(tmp_path / "world.mcap")
    t_ns = 7 * 20_000_000
    stamp = {"sec": (EPOCH_NS + t_ns) // 1_000_000_000, "nsec": (EPOCH_NS + t_ns) % 1_000_000_000}
    assert topics["/vehicle/1/pose"][7] == {
        "timestamp": stamp,
        "frame_id": "ned",
        "pose": {
            "position": {"x": 1.0 + 7 / 3, "y": -2.0, "z": -1.0},
            "orientation": {"x": 0.1, "y": -0.2, "z": 0.3, "w": 0.9},
        },
    }
    assert topics["/vehicle/1/fix"][7] == {
        "timestamp": stamp,
        "frame_id": "wgs84",
        "latitude": 47.0 + 7e-7,
        "longitude": 8.0 - 1e-6,
        "altitude": 488.5 + 7 / 9,
    }
    assert topics["/vehicle/1/state"][7] == {
        "t_s": 0.14,
        "vehicle": 1,
        "pos_ned_m": [1.0 + 7 / 3, -2.0, -1.0],
        "vel_ned_m_s": [0.7000000000000001, 0.2, -0.3],
        "motors": [0.5, None, 0.25, 1.0],  # a non-finite command is null, as JSON has no NaN
        "on_ground": False,
        "crashed": False,
    }
    assert topics["/vehicle/0/state"][2]["motors"] == [0.5, 0.5, 0.25, 2 / 10_000]
    assert topics["/vehicle/0/state"][2]["on_ground"] is True
    assert topics["/sim/tick"][4] == {
        "t_s": 0.08,
        "tick": 20,
        "wall_s": 0.04,
        "real_time_factor": 0.08 / 0.04,
        "tick_wall_us": 37.5,
    }
    assert topics["/sim/tick"][0]["real_time_factor"] == 0.0
    # key order as Foxglove's schemas list them (the JSON text itself)
    with (tmp_path / "world.mcap").open("rb") as f:
        first = next(m for _, c, m in make_reader(f).iter_messages() if c.topic == "/vehicle/0/pose")
    assert list(json.loads(first.data)) == ["timestamp", "frame_id", "pose"]
    assert first.data.startswith(b'{"timestamp":{"sec":1700000000,"nsec":0},"frame_id":"ned","pose":{"position":{"x"')
