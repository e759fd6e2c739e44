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

import functools
import io
import json
import math
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec
from mcap.writer import CompressionType, Writer

from harness.core.clock import NS_PER_S
from harness.record.sample import VehicleSample, gimbal_of
from harness.record.sealed import SealedFile
from harness.wire.protocol import STATUS_GIMBAL

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

_GIMBAL_SCHEMA = {
    "title": "harness.GimbalAttitude",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "t_s": {"type": "number"},
        "vehicle": {"type": "integer"},
        "roll_deg": {"type": "number"},
        "pitch_deg": {"type": "number"},
        "yaw_deg": {"type": "number"},
        "heading_deg": {"type": "number"},
        "orientation": {"type": "object", "properties": {**_XYZ, "w": {"type": "number"}}},
    },
}
"""A vehicle's camera gimbal (``/vehicle/<i>/gimbal``, from the first tick its gimbal was used): as PX4's gimbal
device reports it — roll and pitch earth-stabilised (roll 0: the device has no roll axis), ``yaw_deg`` relative
to the vehicle's heading — then ``heading_deg``, the camera's yaw from north (the vehicle's true heading plus
``yaw_deg``), and ``orientation``, the camera's attitude in the ``ned`` world frame (x along the optical axis)."""

_EVENT_SCHEMA = {
    "title": "harness.Event",
    "type": "object",
    "properties": {"t_s": {"type": "number"}, "kind": {"type": "string"}, "detail": {"type": "object"}},
}


_json = msgspec.json.Encoder().encode


# The messages as structs: built and encoded faster than nested dicts, and the same JSON (fields in this order).
class _Stamp(msgspec.Struct):
    sec: int
    nsec: int


class _Xyz(msgspec.Struct):
    x: float
    y: float
    z: float


class _Xyzw(msgspec.Struct):
    x: float
    y: float
    z: float
    w: float


class _Pose(msgspec.Struct):
    position: _Xyz
    orientation: _Xyzw


class _PoseInFrame(msgspec.Struct):
    timestamp: _Stamp
    frame_id: str
    pose: _Pose


class _LocationFix(msgspec.Struct):
    timestamp: _Stamp
    frame_id: str
    latitude: float
    longitude: float
    altitude: float


class _VehicleState(msgspec.Struct):
    t_s: float
    vehicle: int
    pos_ned_m: tuple[float, ...]
    vel_ned_m_s: tuple[float, ...]
    motors: tuple[float | None, ...]
    on_ground: bool
    crashed: bool


class _GimbalAttitude(msgspec.Struct):
    timestamp: _Stamp
    frame_id: str
    t_s: float
    vehicle: int
    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    heading_deg: float
    orientation: _Xyzw


class _TickTiming(msgspec.Struct):
    t_s: float
    tick: int
    wall_s: float
    real_time_factor: float
    tick_wall_us: float


_isfinite = math.isfinite


def _stamp(unix_ns: int) -> _Stamp:
    return _Stamp(unix_ns // NS_PER_S, unix_ns % NS_PER_S)


_MESSAGE = struct.Struct("<BQHIQQ")
"""An MCAP Message record's opcode, length, channel id, sequence, log time and publish time (then the data)."""
_OP_MESSAGE = 0x05
_OP_MESSAGE_INDEX = 0x07
_OP_CHUNK_INDEX = 0x08


_INDEX_ONE = struct.Struct("<BQHIQQ")
"""A MessageIndex record of one entry (see :func:`_index_record`)."""


@functools.lru_cache(maxsize=256)
def _chunk_index_record(channels: int, compression: int) -> struct.Struct:
    """An MCAP ChunkIndex record with ``channels`` message index offsets and a compression name of
    ``compression`` bytes: opcode, length, start and end time, chunk offset and length, the offsets' length and
    (channel, offset) pairs, the message indexes' length, the compression name, compressed and uncompressed size."""
    return struct.Struct(f"<BQQQQQI{'HQ' * channels}QI{compression}sQQ")


def _write_chunk_index(self: Any, stream: Any) -> None:
    """``ChunkIndex.write`` in one ``struct.pack`` instead of two small writes per channel (a swarm's chunks
    index every vehicle topic, and the summary holds one such record per chunk)."""
    offsets = self.message_index_offsets
    name = self.compression.encode()
    record = _chunk_index_record(len(offsets), len(name))
    stream.write(
        record.pack(
            _OP_CHUNK_INDEX,
            record.size - 9,
            self.message_start_time,
            self.message_end_time,
            self.chunk_start_offset,
            self.chunk_length,
            10 * len(offsets),
            *[x for item in offsets.items() for x in item],
            self.message_index_length,
            len(name),
            name,
            self.compressed_size,
            self.uncompressed_size,
        )
    )


@functools.lru_cache(maxsize=256)
def _index_record(records: int) -> struct.Struct:
    """An MCAP MessageIndex record of ``records`` entries: opcode, length, channel id, entries' length, then
    (log time, offset) per message."""
    return struct.Struct(f"<BQHI{2 * records}Q")


_Add = Callable[[int, int, bytes, int], None]
_AddVehicle = Callable[[int, int, int, int, bytes, bytes, bytes, int], None]


def _appender(w: Writer, chunk_size: int) -> tuple[_Add, _AddVehicle, Callable[[], None]] | None:
    """``add(channel, log_time, data, sequence)``: what ``Writer.add_message`` does for a chunked, uncompressed
    writer — the same records, chunk index, statistics and chunk boundaries — in one ``struct.pack`` instead of
    a dataclass and seven small writes (5.5 us a message; a recording of 100 vehicles adds 15,000 a second of
    sim), and indexes each chunk's messages in records that write themselves in one ``struct.pack`` too. It
    works on the writer's chunk builder, so it is used only when this ``mcap`` has the one it knows (``None``
    otherwise: ``Writer.add_message`` then). ``tests/record/test_world.py`` checks that both write the same
    bytes. ``add_vehicle(c1, c2, c3, log_time, d1, d2, d3, sequence)``: three messages of one log time on
    sequences ``sequence`` … ``sequence + 2`` (a vehicle's recorded tick), the same records as three ``add``
    calls, with the statistics updated once and the records written at once while they leave the chunk below
    its size (else one by one: the chunk ends after the same message). ``before_finish()``: the chunk indexes
    (the summary's) to write themselves in one ``struct.pack`` each (:func:`_write_chunk_index`)."""
    try:
        chunk_indices = w._Writer__chunk_indices  # type: ignore[attr-defined]
        stats = w._Writer__statistics  # type: ignore[attr-defined]
        chunk = w._Writer__chunk_builder  # type: ignore[attr-defined]
        finalize = w._Writer__finalize_chunk  # type: ignore[attr-defined]
        ok = (
            isinstance(chunk.record_writer._buffer, io.BytesIO)
            and isinstance(chunk.message_indices, dict)
            and isinstance(chunk.num_messages, int)
            and isinstance(stats.message_count, int)
            and hasattr(stats.channel_message_counts, "__getitem__")
            and isinstance(chunk_indices, list)
        )
    except AttributeError:
        return None
    if not ok:
        return None
    from mcap.records import ChunkIndex, MessageIndex

    class _ChunkIndex(ChunkIndex):
        write = _write_chunk_index

    def before_finish() -> None:
        for index in chunk_indices:
            if type(index) is ChunkIndex:
                index.__class__ = _ChunkIndex

    class _Index(MessageIndex):
        """A chunk's index of one channel, written by the writer when the chunk ends: the same record as
        ``MessageIndex.write``'s, in one ``struct.pack`` instead of two small writes per message (each chunk of
        a swarm's recording holds one index per vehicle topic)."""

        def write(self, stream: Any) -> None:
            records = self.records
            if len(records) == 1:  # a swarm's chunk holds one or two messages of each vehicle topic
                ((log_time, offset),) = records
                stream.write(_INDEX_ONE.pack(_OP_MESSAGE_INDEX, 22, self.channel_id, 16, log_time, offset))
                return
            size = 16 * len(records)
            stream.write(
                _index_record(len(records)).pack(
                    _OP_MESSAGE_INDEX, 6 + size, self.channel_id, size, *[x for record in records for x in record]
                )
            )

    pack = _MESSAGE.pack

    def add(channel: int, log_time: int, data: bytes, sequence: int) -> None:
        if stats.message_count == 0 or log_time < stats.message_start_time:
            stats.message_start_time = log_time
        if log_time > stats.message_end_time:
            stats.message_end_time = log_time
        stats.channel_message_counts[channel] += 1
        stats.message_count += 1
        if chunk.num_messages == 0 or log_time < chunk.message_start_time:
            chunk.message_start_time = log_time
        if log_time > chunk.message_end_time:
            chunk.message_end_time = log_time
        buf = chunk.record_writer._buffer  # a new one after each chunk
        offset = buf.tell()
        index = chunk.message_indices.get(channel)
        if index is None:
            index = chunk.message_indices[channel] = _Index(channel_id=channel, records=[])
        index.records.append((log_time, offset))
        chunk.num_messages += 1
        buf.write(pack(_OP_MESSAGE, 22 + len(data), channel, sequence, log_time, log_time))
        buf.write(data)
        if buf.tell() > chunk_size:
            finalize()

    def add_vehicle(c1: int, c2: int, c3: int, log_time: int, d1: bytes, d2: bytes, d3: bytes, sequence: int) -> None:
        buf = chunk.record_writer._buffer
        o1 = buf.tell()
        o2 = o1 + 31 + len(d1)  # a Message record: 1 opcode + 8 length + 22 of header, then the data
        o3 = o2 + 31 + len(d2)
        if o3 + 31 + len(d3) > chunk_size:  # the chunk ends within or after these: one by one, as add does
            add(c1, log_time, d1, sequence)
            add(c2, log_time, d2, sequence + 1)
            add(c3, log_time, d3, sequence + 2)
            return
        if stats.message_count == 0 or log_time < stats.message_start_time:
            stats.message_start_time = log_time
        if log_time > stats.message_end_time:
            stats.message_end_time = log_time
        counts = stats.channel_message_counts
        counts[c1] += 1
        counts[c2] += 1
        counts[c3] += 1
        stats.message_count += 3
        if chunk.num_messages == 0 or log_time < chunk.message_start_time:
            chunk.message_start_time = log_time
        if log_time > chunk.message_end_time:
            chunk.message_end_time = log_time
        indices = chunk.message_indices
        for channel, offset in ((c1, o1), (c2, o2), (c3, o3)):
            index = indices.get(channel)
            if index is None:
                index = indices[channel] = _Index(channel_id=channel, records=[])
            index.records.append((log_time, offset))
        chunk.num_messages += 3
        buf.write(
            b"".join(
                (
                    pack(_OP_MESSAGE, 22 + len(d1), c1, sequence, log_time, log_time),
                    d1,
                    pack(_OP_MESSAGE, 22 + len(d2), c2, sequence + 1, log_time, log_time),
                    d2,
                    pack(_OP_MESSAGE, 22 + len(d3), c3, sequence + 2, log_time, log_time),
                    d3,
                )
            )
        )

    return add, add_vehicle, before_finish


class WorldRecorder:
    """Writes ``world.mcap``. Not thread-safe: one writer thread (the physics loop)."""

    def __init__(self, path: Path, epoch_ns: int, n_vehicles: int) -> None:
        self.path = path
        self.epoch_ns = epoch_ns
        self._file = SealedFile(path)
        chunk_size = 64 * 1024
        self._w = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.NONE)  # type: ignore[arg-type]
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
        self._gimbal: dict[int, int] = {}
        """Each vehicle's gimbal channel, registered (with the schema) at its first gimbal sample: a run whose
        vehicles never used a gimbal writes the file it wrote before there were gimbals."""
        self._gimbal_schema = 0
        self._seq = 0
        self.closed = False
        fast = _appender(self._w, chunk_size)
        self._add: _Add = fast[0] if fast else self._add_message
        self._add_vehicle: _AddVehicle = fast[1] if fast else self._add_vehicle_messages
        self._before_finish: Callable[[], None] | None = fast[2] if fast else None
        self._stamp_t_ns = -1
        self._stamp = _stamp(epoch_ns)
        """The stamp of the last sample's time: every vehicle of a recorded tick has the same."""

    def _add_message(self, channel: int, log_time: int, data: bytes, sequence: int) -> None:
        self._w.add_message(channel, log_time, data, log_time, sequence)

    def _add_vehicle_messages(
        self, c1: int, c2: int, c3: int, log_time: int, d1: bytes, d2: bytes, d3: bytes, sequence: int
    ) -> None:
        self._add_message(c1, log_time, d1, sequence)
        self._add_message(c2, log_time, d2, sequence + 1)
        self._add_message(c3, log_time, d3, sequence + 2)

    def _put(self, channel: int, t_ns: int, obj: Any) -> None:
        self._seq += 1
        self._add(channel, self.epoch_ns + t_ns, _json(obj), self._seq)

    def vehicle(self, s: VehicleSample) -> None:
        t_ns, vehicle, motors = s.t_ns, s.vehicle, s.motors
        log_time = self.epoch_ns + t_ns
        if t_ns != self._stamp_t_ns:
            self._stamp_t_ns, self._stamp = t_ns, _stamp(log_time)
        stamp = self._stamp
        pos = s.pos_ned_m
        w, x, y, z = s.quat_wxyz
        if not all(map(_isfinite, motors)):
            motors = tuple(m if _isfinite(m) else None for m in motors)  # type: ignore[misc]
        json = _json
        seq = self._seq
        self._seq = seq + 3
        state = _VehicleState(t_ns / NS_PER_S, vehicle, pos, s.vel_ned_m_s, motors, s.on_ground, s.crashed)
        self._add_vehicle(
            self._pose[vehicle],
            self._fix[vehicle],
            self._state[vehicle],
            log_time,
            json(_PoseInFrame(stamp, "ned", _Pose(_Xyz(pos[0], pos[1], pos[2]), _Xyzw(x, y, z, w)))),
            json(_LocationFix(stamp, "wgs84", s.lat_deg, s.lon_deg, s.alt_amsl_m)),
            json(state),
            seq + 1,
        )
        if s.status & STATUS_GIMBAL:
            self._gimbal_sample(s, stamp, log_time)

    def _gimbal_sample(self, s: VehicleSample, stamp: _Stamp, log_time: int) -> None:
        g = gimbal_of(s)
        if g is None:
            return
        channel = self._gimbal.get(s.vehicle)
        if channel is None:
            if not self._gimbal_schema:
                data = json.dumps(_GIMBAL_SCHEMA).encode()
                self._gimbal_schema = self._w.register_schema("harness.GimbalAttitude", "jsonschema", data)
            channel = self._gimbal[s.vehicle] = self._w.register_channel(
                f"/vehicle/{s.vehicle}/gimbal", "json", self._gimbal_schema
            )
        w, x, y, z = g.quat_wxyz
        msg = _GimbalAttitude(
            stamp, "ned", s.t_ns / NS_PER_S, s.vehicle, 0.0, g.pitch_deg, g.yaw_deg, g.heading_deg, _Xyzw(x, y, z, w)
        )
        self._seq += 1
        self._add(channel, log_time, _json(msg), self._seq)

    def tick(self, t_ns: int, tick: int, wall_s: float, tick_wall_us: float) -> None:
        t_s = t_ns / NS_PER_S
        rtf = t_s / wall_s if wall_s > 0 else 0.0
        self._put(self._tick, t_ns, _TickTiming(t_s, tick, wall_s, rtf, tick_wall_us))

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
        try:
            self._w.flush()  # the last chunk while the file is sealed: a failure leaves the file valid
            self._file.unseal()
            if self._before_finish is not None:
                self._before_finish()
            self._w.finish()
        except OSError:
            self._file.abandon()
            raise
        self._file.close()

    def abandon(self) -> None:
        """After a write failed (a full disk): no more writes; the file holds every chunk written before."""
        self.closed = True
        self._file.abandon()


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
