"""``world.rrd``: the run as a Rerun recording — the 3D view of the swarm, live or afterwards.

A thin writer: what the scene shows and when it changes is the pure model in ``harness.record.scene``; this
module reads its inputs (samples, the in-process autopilots, ``network-events.jsonl``) and turns the
scene's updates, and the sampled poses and series, into Rerun calls.

It is fed exactly what ``world.mcap`` is fed (``harness.record.sink.WorldSink``: the ground truth of every
vehicle at the record rate, the tick timing, events), plus what only the view needs and reads itself at
each flush: the autopilots' state (mode, battery, home, mission items, geofence) and the network events
the network process appends to ``network-events.jsonl``.

Everything is on the ``sim_time`` timeline. Samples are buffered and sent in columns (one call per
entity per batch, not per sample); a batch goes out when it holds ``batch_s`` of sim time and
``min_wall_s`` of wall time has passed since the last one — so a fast run costs a few calls per wall
tenth of a second, whatever its speed. Rerun's own sinks encode and write on their threads; a gRPC
server sink with no viewer keeps at most its memory limit and drops the oldest data, so nothing waits for
a viewer.

Entities (``world`` is NED, x north, y east, z down, as ``ViewCoordinates.FRD``):

- ``world/vehicle/<i>``: the body transform (true position and attitude); under it a quad-X drawn at
  ``BODY_SCALE`` times its size so it shows in a swarm-wide view, labelled with name and mode;
- ``world/gimbal/<i>``: from the first time vehicle ``i``'s gimbal was used, the camera's transform (at the
  vehicle, with the gimbal's pitch and its yaw composed with the vehicle's true heading: ``GimbalSample``);
  under it ``camera`` (a frustum) and ``axis`` (the optical axis, an arrow);
- ``world/trails``, ``world/velocity``, ``world/markers``: the last ``trail_s`` of every vehicle's path; its
  velocity vector; a dot of fixed screen size on it (visible at any zoom);
- ``world/spawn``, ``world/home``, ``world/mission/<i>``, ``world/geofence/<i>``: spawn and home points,
  the mission items and geofence each autopilot holds (changes are logged when they happen);
- ``world/links``, ``world/drops``: radio links coloured by their recent delivery ratio, drops in red;
- ``series/*``: altitude, speed, battery, link quality per vehicle, real-time factor;
- ``map/vehicles``: latitude and longitude for the map view (needs map tiles, i.e. a network; the 3D
  view needs nothing);
- ``world/captures/<i>``: the points where vehicle ``i``'s camera took its pictures, and under it ``frustum``,
  the last picture's frustum from the camera down to the ground (its footprint);
- ``events``: the run's events (pause, crash, ...) as a text log.
"""

from __future__ import annotations

import logging
import math
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from harness.autopilot.camera import Capture
from harness.core.clock import NS_PER_S, WALL, Clock
from harness.record.sample import VehicleSample, WorldEvent, gimbal_of
from harness.record.scene import (
    BODY_SCALE,
    MODE_DT_S,
    VIEW_STEP_S,
    AutopilotReadout,
    Battery,
    FenceLines,
    Homes,
    Label,
    Links,
    MissionPath,
    SampleBatch,
    Scene,
    Spawn,
    Trails,
    Update,
    camera_frustum,
    vehicle_color,
)
from harness.wire.protocol import STATUS_GIMBAL

if TYPE_CHECKING:
    from harness.autopilot.services import System

log = logging.getLogger(__name__)


class RrdRecorder:
    """Writes ``world.rrd`` (and, with ``serve_port``, serves the same stream to live viewers over gRPC).

    Not thread-safe: one writer thread (the physics loop), like ``WorldRecorder``.
    """

    def __init__(
        self,
        path: Path,
        n_vehicles: int,
        origin: tuple[float, float, float],
        *,
        serve_port: int | None = None,
        batch_s: float = 0.5,
        min_wall_s: float = 0.1,
        trail_s: float = 30.0,
        events_path: Path | None = None,
        application_id: str = "uav-harness",
        clock: Clock = WALL,
    ) -> None:
        import rerun as rr

        from harness.record.blueprint import blueprint

        self._rr = rr
        self.path = path
        self.n = n_vehicles
        self.origin = origin
        self.batch_s = batch_s
        self.min_wall_s = min_wall_s
        self._clock = clock
        self.trail_s = trail_s
        self.view_step_s = VIEW_STEP_S / 2 if serve_port is not None else VIEW_STEP_S
        """Trails and links every second of sim; every half second live (a trail keeps up with its body)."""
        self.events_path = events_path
        self.closed = False
        self.grpc_url: str | None = None
        # a fresh id per run: two recordings opened in one viewer must not merge into one
        self._rec = rr.RecordingStream(
            application_id, recording_id=f"{path.parent.name or 'run'}-{uuid.uuid4().hex[:8]}"
        )
        sinks: list[Any] = [rr.FileSink(str(path))]
        if serve_port is not None:
            sinks.append(rr.GrpcServerSink("127.0.0.1", serve_port, server_memory_limit="512MiB"))
            self.grpc_url = f"rerun+http://127.0.0.1:{serve_port}/proxy"
        self._rec.set_sinks(*sinks, default_blueprint=blueprint(n_vehicles))
        self._buf = SampleBatch(n_vehicles)
        self._last_flush_wall = clock.now_ns()
        self._scene = Scene(n_vehicles, origin, trail_s, self.view_step_s)
        self._aps: Mapping[int, System] = {}
        self._mode_t: float | None = None
        self._labels: list[Label] = []
        """Label changes sampled since the last batch."""
        self._status: dict[int, int] = {}
        """The last END-TICK-AC status of each vehicle whose autopilot is not in this process (its label)."""
        self._gimbals: dict[int, tuple[list[float], list[Any], list[Any]]] = {}
        """Each vehicle's gimbal samples of this batch (times, positions, camera quaternions xyzw)."""
        self._gimbal_shown: set[int] = set()
        self._captures: dict[int, list[tuple[float, float, float]]] = {}
        """Each vehicle's capture points so far."""
        self._events_file: Any = None
        self._events_rest = b""
        self._static()

    # -- the WorldSink interface --------------------------------------------------------------------------

    def vehicle(self, s: VehicleSample) -> None:
        w, x, y, z = s.quat_wxyz
        self._buf.add(s.t_ns / NS_PER_S, s.vehicle, (s.pos_ned_m, (x, y, z, w), s.vel_ned_m_s, (s.lat_deg, s.lon_deg)))
        if s.status and s.vehicle not in self._aps:
            self._status[s.vehicle] = s.status
        if s.status & STATUS_GIMBAL:
            g = gimbal_of(s)
            if g is not None:
                t, positions, quats = self._gimbals.setdefault(s.vehicle, ([], [], []))
                gw, gx, gy, gz = g.quat_wxyz
                t.append(s.t_ns / NS_PER_S)
                positions.append(s.pos_ned_m)
                quats.append((gx, gy, gz, gw))

    def tick(self, t_ns: int, tick: int, wall_s: float, tick_wall_us: float) -> None:
        t_s = t_ns / NS_PER_S
        if (self._aps or self._status) and (self._mode_t is None or t_s - self._mode_t >= MODE_DT_S - 1e-9):
            self._mode_t = t_s
            self._sample_labels(t_s)
        self._buf.tick_t_s.append(t_s)
        self._buf.rtf.append(t_s / wall_s if wall_s > 0 else 0.0)
        if self._buf.span_s() >= self.batch_s:
            now = self._clock.now_ns()
            if now - self._last_flush_wall >= self.min_wall_s * NS_PER_S or self._buf.span_s() >= 60.0:
                self._last_flush_wall = now
                self._send_batch()

    def event(self, t_ns: int, kind: str, detail: dict[str, Any]) -> None:
        rr = self._rr
        self._rec.set_time("sim_time", duration=t_ns / NS_PER_S)
        text = kind + (" " + " ".join(f"{k}={v}" for k, v in detail.items()) if detail else "")
        level = rr.TextLogLevel.ERROR if kind == WorldEvent.CRASH else rr.TextLogLevel.INFO
        self._rec.log("events", rr.TextLog(text, level=level))

    def capture(self, vehicle: int, c: Capture) -> None:
        """The picture's point (with the vehicle's earlier ones) and its frustum down to the ground: the image's
        footprint, drawn with the camera fixed to the body looking straight down."""
        rr = self._rr
        self._rec.set_time("sim_time", duration=c.t_ns / NS_PER_S)
        pts = self._captures.setdefault(vehicle, [])
        pts.append(c.pos_ned_m)
        color = vehicle_color(vehicle)
        self._rec.log(f"world/captures/{vehicle}", rr.Points3D(pts, colors=[color], radii=0.25))
        w, x, y, z = c.q
        self._rec.log(
            f"world/captures/{vehicle}/frustum",
            rr.Transform3D(translation=c.pos_ned_m, quaternion=rr.Quaternion(xyzw=[x, y, z, w])),
        )
        depth = max(0.5, -c.pos_ned_m[2])  # to the ground (the origin's level)
        down = [[(-p[2], p[1], p[0]) for p in strip] for strip in camera_frustum(depth)]  # optical axis: body z
        self._rec.log(f"world/captures/{vehicle}/frustum/lines", rr.LineStrips3D(down, colors=[color], radii=0.05))

    def flush(self) -> None:
        self._send_batch()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self._buf.close_row()
            self._send_batch()
            self._rec.flush()
        finally:
            self._rec.disconnect()
            if self._events_file is not None:
                self._events_file.close()

    # -- extra inputs ----------------------------------------------------------------------------------------

    def attach_autopilots(self, aps: Mapping[int, System]) -> None:
        """The in-process autopilots, read at each batch for mode, battery, home, mission and geofence."""
        self._aps = aps

    # -- internals ----------------------------------------------------------------------------------------

    def _static(self) -> None:
        rr = self._rr
        rec = self._rec
        rec.log("world", rr.ViewCoordinates.FRD, static=True)
        arm = 0.25 * BODY_SCALE
        for i in range(self.n):
            color = vehicle_color(i)
            base = f"world/vehicle/{i}"
            rotors = [
                (arm * math.cos(a), arm * math.sin(a), 0.0)
                for a in (math.radians(45), math.radians(-45), math.radians(-135), math.radians(135))
            ]
            rec.log(
                f"{base}/arms",
                rr.LineStrips3D([[(0, 0, 0), r] for r in rotors], colors=[color], radii=0.05 * BODY_SCALE),
                static=True,
            )
            rec.log(
                f"{base}/rotors",
                rr.Ellipsoids3D(
                    centers=rotors,
                    half_sizes=[(0.12 * BODY_SCALE, 0.12 * BODY_SCALE, 0.02 * BODY_SCALE)] * 4,
                    colors=[color, color, (200, 200, 200), (200, 200, 200)],  # front pair in colour: heading
                    fill_mode=rr.components.FillMode.Solid,
                ),
                static=True,
            )
            rec.log(
                f"{base}/body",
                rr.Boxes3D(
                    half_sizes=[(0.12 * BODY_SCALE, 0.08 * BODY_SCALE, 0.04 * BODY_SCALE)],
                    colors=[color],
                    fill_mode=rr.components.FillMode.Solid,
                ),
                static=True,
            )  # its label (name and mode) is logged on the timeline: static data would hide it
        colors = [vehicle_color(i) for i in range(self.n)]
        rec.log("world/markers", rr.Points3D.from_fields(colors=colors, radii=-5.0), static=True)
        rec.log("map/vehicles", rr.GeoPoints.from_fields(colors=colors, radii=-6.0), static=True)
        names = [f"vehicle {i}" for i in range(self.n)]
        for series in ("altitude_m", "speed_m_s", "battery_pct", "link_delivery_pct"):
            rec.log(f"series/{series}", rr.SeriesLines(names=names, colors=colors), static=True)
        rec.log(
            "series/real_time_factor", rr.SeriesLines(names=["real-time factor"], colors=[(220, 220, 220)]), static=True
        )

    def _send_batch(self) -> None:
        b = self._buf
        if b.t_s:
            self._send_vehicles(b)
        if self._gimbals:
            self._send_gimbals()
        if b.tick_t_s:
            rr = self._rr
            self._rec.send_columns(
                "series/real_time_factor",
                indexes=[rr.TimeColumn("sim_time", duration=np.asarray(b.tick_t_s))],
                columns=rr.Scalars.columns(scalars=np.asarray(b.rtf)),
            )
        for label in self._labels:
            self._write(label)
        self._labels.clear()
        if b.t_s:
            now_s = b.t_s[-1]
            self._rec.set_time("sim_time", duration=now_s)
            for update in self._scene.autopilots(self._read_autopilots()):
                self._write(update)
        b.clear()

    def _sample_labels(self, t_s: float) -> None:
        """Each vehicle's name, flight mode and armed state now, kept when it changed (logged with the batch)."""
        labels = self._labels
        for i, ap in sorted(self._aps.items()):
            try:
                st = ap.telemetry.state()
            except Exception as exc:  # the view must never end a run
                log.debug("view: autopilot %d not readable: %r", i, exc)
                continue
            label = self._scene.label(t_s, i, st.mode.name, st.armed)
            if label is not None:
                labels.append(label)
        if self._status:
            from harness.autopilot.api import FlightMode
            from harness.wire.protocol import unpack_status

            for i, status in sorted(self._status.items()):  # flown in another process: mode from its status
                armed, _, main, sub = unpack_status(status)
                mode = FlightMode.from_px4(main, sub)
                label = self._scene.label(t_s, i, mode.name if mode is not None else f"mode {main}.{sub}", armed)
                if label is not None:
                    labels.append(label)

    def _read_autopilots(self) -> dict[int, AutopilotReadout]:
        if not self._aps:
            return {}
        from harness.autopilot.api import MissionKind

        out = {}
        for i, ap in sorted(self._aps.items()):
            try:
                st = ap.telemetry.state()
                mission = ap.mission.download(MissionKind.MISSION)
                fence = ap.mission.download(MissionKind.FENCE)
            except Exception as exc:  # the view must never end a run
                log.debug("view: autopilot %d not readable: %r", i, exc)
                continue
            home_amsl = st.home.alt_amsl_m if st.home is not None else None
            out[i] = AutopilotReadout(
                100.0 * st.battery.remaining, home_amsl, st.home_ned_m, mission, fence, st.fence_max_hor_m
            )
        return out

    def _send_vehicles(self, b: SampleBatch) -> None:
        rr = self._rr
        rec = self._rec
        n, k = self.n, len(b.t_s)
        times = [rr.TimeColumn("sim_time", duration=np.asarray(b.t_s))]
        pos = np.asarray(b.pos, dtype=np.float64)  # (k, n, 3)
        quat = np.asarray(b.quat_xyzw, dtype=np.float64)
        vel = np.asarray(b.vel, dtype=np.float64)
        latlon = np.asarray(b.latlon, dtype=np.float64)
        for i in range(n):
            rec.send_columns(
                f"world/vehicle/{i}",
                indexes=times,
                columns=rr.Transform3D.columns(translation=pos[:, i, :], quaternion=quat[:, i, :]),
            )
        rec.send_columns(
            "world/velocity",
            indexes=times,
            columns=rr.Arrows3D.columns(origins=pos.reshape(-1, 3), vectors=vel.reshape(-1, 3)).partition([n] * k),
        )
        rec.send_columns(  # a dot of fixed screen size on each vehicle: visible at any zoom
            "world/markers",
            indexes=times,
            columns=rr.Points3D.columns(positions=pos.reshape(-1, 3)).partition([n] * k),
        )
        rec.send_columns(
            "map/vehicles",
            indexes=times,
            columns=rr.GeoPoints.columns(positions=latlon.reshape(-1, 2)).partition([n] * k),
        )
        rec.send_columns("series/altitude_m", indexes=times, columns=rr.Scalars.columns(scalars=-pos[:, :, 2]))
        rec.send_columns(
            "series/speed_m_s", indexes=times, columns=rr.Scalars.columns(scalars=np.linalg.norm(vel, axis=2))
        )
        self._read_events()  # trails (a point per TRAIL_DT_S) and radio links: a state every view_step_s of sim
        for update in self._scene.batch(b.t_s, pos, self._labels):
            self._write(update)

    def _send_gimbals(self) -> None:
        rr = self._rr
        rec = self._rec
        for i, (t, positions, quats) in sorted(self._gimbals.items()):
            base = f"world/gimbal/{i}"
            if i not in self._gimbal_shown:  # drawn from its first sample on: no camera at the origin before
                self._gimbal_shown.add(i)
                rec.set_time("sim_time", duration=t[0])
                color = vehicle_color(i)
                rec.log(f"{base}/camera", rr.LineStrips3D(camera_frustum(), colors=[color], radii=0.03))
                rec.log(f"{base}/axis", rr.Arrows3D(vectors=[(1.5 * BODY_SCALE, 0.0, 0.0)], colors=[color], radii=0.03))
            rec.send_columns(
                base,
                indexes=[rr.TimeColumn("sim_time", duration=np.asarray(t))],
                columns=rr.Transform3D.columns(
                    translation=np.asarray(positions, dtype=np.float64), quaternion=np.asarray(quats, dtype=np.float64)
                ),
            )
        self._gimbals.clear()

    def _read_events(self) -> None:
        if self.events_path is None:
            return
        if self._events_file is None:
            if not self.events_path.exists():
                return
            self._events_file = self.events_path.open("rb")
        data = self._events_rest + self._events_file.read()
        lines = data.split(b"\n")
        self._events_rest = lines.pop()  # an incomplete last line waits for the next batch
        self._scene.links.add_lines([line for line in lines if line])

    # -- the scene's updates as Rerun calls ---------------------------------------------------------------

    def _write(self, u: Update) -> None:
        rr = self._rr
        rec = self._rec
        if isinstance(u, Trails):
            rec.set_time("sim_time", duration=u.t_s)
            colors = [vehicle_color(i) for i in range(self.n)]
            rec.log("world/trails", rr.LineStrips3D(list(u.strips), colors=colors, radii=0.08))
        elif isinstance(u, Links):
            lines = [list(line) for line in u.lines]
            rec.log("world/links", rr.LineStrips3D(lines, colors=list(u.colors), radii=0.05, labels=list(u.labels)))
            rec.log("world/drops", rr.Points3D(list(u.drops), colors=[(255, 0, 0)] * len(u.drops), radii=0.6))
            if u.per_vehicle_pct is not None:
                rec.log("series/link_delivery_pct", rr.Scalars(list(u.per_vehicle_pct)))
        elif isinstance(u, Spawn):
            rec.set_time("sim_time", duration=u.t_s)
            for i, first in enumerate(u.labels):
                rec.log(f"world/vehicle/{i}/body", rr.Boxes3D.from_fields(labels=[first], show_labels=True))
            colors = [vehicle_color(i) for i in range(self.n)]
            rec.log("world/spawn", rr.Points3D(u.points, colors=colors, radii=0.3), static=True)
        elif isinstance(u, Label):
            rec.set_time("sim_time", duration=u.t_s)
            rec.log(f"world/vehicle/{u.vehicle}/body", rr.Boxes3D.from_fields(labels=[u.text]))
        elif isinstance(u, MissionPath):
            path = f"world/mission/{u.vehicle}"
            if not u.points:
                rec.log(path, rr.Clear(recursive=True))
                return
            color = vehicle_color(u.vehicle)
            pts = list(u.points)
            labels = [str(k) for k in range(len(pts))]
            rec.log(
                path,
                rr.LineStrips3D([pts], colors=[color], radii=0.04),
                rr.Points3D(pts, colors=[color], radii=0.25, labels=labels),
            )
        elif isinstance(u, FenceLines):
            path = f"world/geofence/{u.vehicle}"
            if not u.strips:
                rec.log(path, rr.Clear(recursive=True))
                return
            strips = [list(strip) for strip in u.strips]
            rec.log(path, rr.LineStrips3D(strips, colors=[(*vehicle_color(u.vehicle), 160)], radii=0.06))
        elif isinstance(u, Homes):
            colors = [vehicle_color(i) for i in u.vehicles]
            rec.log("world/home", rr.Points3D(list(u.points), colors=colors, radii=0.4))
        elif isinstance(u, Battery):
            rec.log("series/battery_pct", rr.Scalars(list(u.pct)))
