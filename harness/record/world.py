"""``world.mcap``: ground truth of every vehicle, network events and tick timing of a whole run.

Messages are JSON with JSON-Schema schemas, so Foxglove shows them: poses use the layout of Foxglove's
``foxglove.PoseInFrame`` (``timestamp``, ``frame_id``, ``pose.position``, ``pose.orientation``) and
``foxglove.LocationFix`` for the geodetic position. Log times are *sim* time in nanoseconds (since the
run's epoch), so a recording replays at sim speed.

The file is a valid MCAP file at every instant (``sealed.py``): a run stopped by Ctrl-C finishes it with its
summary; a run killed with ``kill -9`` leaves every chunk written so far readable by ``mcap.reader.make_reader``
— the run flushes the chunk in progress every second of wall time (:meth:`WorldRecorder.flush`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import msgspec
from mcap.writer import CompressionType, Writer

from harness.core.clock import NS_PER_S
from harness.record.sample import VehicleSample
from harness.record.sealed import SealedFile

_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
_XYZ = {"x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}}

_POSE_SCHEMA = {
    "title": "foxglove.PoseInFrame",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "pose": {
            "type": "object",
            "properties": {
                "position": {"type": "object", "properties": _XYZ},
                "orientation": {"type": "object", "properties": {**_XYZ, "w": {"type": "number"}}},
            },
        },
    },
}

_FIX_SCHEMA = {
    "title": "foxglove.LocationFix",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "latitude": {"type": "number"},
        "longitude": {"type": "number"},
        "altitude": {"type": "number"},
    },
}

_STATE_SCHEMA = {
    "title": "harness.VehicleState",
    "type": "object",
    "properties": {
        "t_s": {"type": "number"},
        "vehicle": {"type": "integer"},
        "pos_ned_m": {"type": "array", "items": {"type": "number"}},
        "vel_ned_m_s": {"type": "array", "items": {"type": "number"}},
        "motors": {"type": "array", "items": {"type": "number"}},
        "on_ground": {"type": "boolean"},
        "crashed": {"type": "boolean"},
    },
}

_TICK_SCHEMA = {
    "title": "harness.TickTiming",
    "type": "object",
    "properties": {
        "t_s": {"type": "number"},
        "tick": {"type": "integer"},
        "wall_s": {"type": "number"},
        "real_time_factor": {"type": "number"},
        "tick_wall_us": {"type": "number"},
    },
}

_EVENT_SCHEMA = {
    "title": "harness.Event",
    "type": "object",
    "properties": {"t_s": {"type": "number"}, "kind": {"type": "string"}, "detail": {"type": "object"}},
}


_json = msgspec.json.Encoder().encode


def _stamp(unix_ns: int) -> dict[str, int]:
    return {"sec": unix_ns // NS_PER_S, "nsec": unix_ns % NS_PER_S}


class WorldRecorder:
    """Writes ``world.mcap``. Not thread-safe: one writer thread (the physics loop)."""

    def __init__(self, path: Path, epoch_ns: int, n_vehicles: int) -> None:
        self.path = path
        self.epoch_ns = epoch_ns
        self._file = SealedFile(path)
        self._w = Writer(self._file, chunk_size=64 * 1024, compression=CompressionType.NONE)  # type: ignore[arg-type]
        self._w.start(profile="", library="uav-harness")
        schema = {
            name: self._w.register_schema(name=name, encoding="jsonschema", data=json.dumps(s).encode())
            for name, s in (
                ("foxglove.PoseInFrame", _POSE_SCHEMA),
                ("foxglove.LocationFix", _FIX_SCHEMA),
                ("harness.VehicleState", _STATE_SCHEMA),
                ("harness.TickTiming", _TICK_SCHEMA),
                ("harness.Event", _EVENT_SCHEMA),
            )
        }
        self._pose = [
            self._w.register_channel(f"/vehicle/{i}/pose", "json", schema["foxglove.PoseInFrame"])
            for i in range(n_vehicles)
        ]
        self._fix = [
            self._w.register_channel(f"/vehicle/{i}/fix", "json", schema["foxglove.LocationFix"])
            for i in range(n_vehicles)
        ]
        self._state = [
            self._w.register_channel(f"/vehicle/{i}/state", "json", schema["harness.VehicleState"])
            for i in range(n_vehicles)
        ]
        self._tick = self._w.register_channel("/sim/tick", "json", schema["harness.TickTiming"])
        self._event = self._w.register_channel("/sim/events", "json", schema["harness.Event"])
        self._seq = 0
        self.closed = False

    def _put(self, channel: int, t_ns: int, obj: Any) -> None:
        self._seq += 1
        log_time = self.epoch_ns + t_ns
        self._w.add_message(channel, log_time, _json(obj), log_time, self._seq)

    def vehicle(self, s: VehicleSample) -> None:
        t_ns, vehicle, pos_ned_m, vel_ned_m_s, motors = s.t_ns, s.vehicle, s.pos_ned_m, s.vel_ned_m_s, s.motors
        stamp = _stamp(self.epoch_ns + t_ns)
        w, x, y, z = s.quat_wxyz
        self._put(
            self._pose[vehicle],
            t_ns,
            {
                "timestamp": stamp,
                "frame_id": "ned",
                "pose": {
                    "position": {"x": pos_ned_m[0], "y": pos_ned_m[1], "z": pos_ned_m[2]},
                    "orientation": {"x": x, "y": y, "z": z, "w": w},
                },
            },
        )
        self._put(
            self._fix[vehicle],
            t_ns,
            {
                "timestamp": stamp,
                "frame_id": "wgs84",
                "latitude": s.lat_deg,
                "longitude": s.lon_deg,
                "altitude": s.alt_amsl_m,
            },
        )
        self._put(
            self._state[vehicle],
            t_ns,
            {
                "t_s": t_ns / NS_PER_S,
                "vehicle": vehicle,
                "pos_ned_m": list(pos_ned_m),
                "vel_ned_m_s": list(vel_ned_m_s),
                "motors": [m if math.isfinite(m) else None for m in motors],
                "on_ground": s.on_ground,
                "crashed": s.crashed,
            },
        )

    def tick(self, t_ns: int, tick: int, wall_s: float, tick_wall_us: float) -> None:
        rtf = (t_ns / NS_PER_S) / wall_s if wall_s > 0 else 0.0
        self._put(
            self._tick,
            t_ns,
            {
                "t_s": t_ns / NS_PER_S,
                "tick": tick,
                "wall_s": wall_s,
                "real_time_factor": rtf,
                "tick_wall_us": tick_wall_us,
            },
        )

    def event(self, t_ns: int, kind: str, detail: dict[str, Any]) -> None:
        self._put(self._event, t_ns, {"t_s": t_ns / NS_PER_S, "kind": kind, "detail": detail})

    def flush(self) -> None:
        """The chunk in progress to disk (a valid file up to here, even if the process is killed next)."""
        if not self.closed:
            self._w.flush()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._file.unseal()
        self._w.finish()
        self._file.close()


def read_topics(path: Path) -> dict[str, list[Any]]:
    """Every message of a recording, decoded, by topic (tests, plots). Works on unfinished files."""
    from mcap.stream_reader import StreamReader

    out: dict[str, list[Any]] = {}
    channels: dict[int, str] = {}
    with path.open("rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                kind = type(record).__name__
                if kind == "Channel":
                    channels[record.id] = record.topic  # type: ignore[attr-defined]
                elif kind == "Message":
                    topic = channels.get(record.channel_id)  # type: ignore[attr-defined]
                    if topic is not None:
                        out.setdefault(topic, []).append(json.loads(record.data))  # type: ignore[attr-defined]
        except Exception:  # a truncated file (killed run): keep what was complete
            pass
    return out
