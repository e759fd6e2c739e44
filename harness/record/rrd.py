"""``world.rrd``: the run as a Rerun recording — the 3D view of the swarm, live or afterwards.

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
- ``world/trails``, ``world/velocity``, ``world/markers``: the last ``trail_s`` of every vehicle's path; its
  velocity vector; a dot of fixed screen size on it (visible at any zoom);
- ``world/spawn``, ``world/home``, ``world/mission/<i>``, ``world/geofence/<i>``: spawn and home points,
  the mission items and geofence each autopilot holds (changes are logged when they happen);
- ``world/links``, ``world/drops``: radio links coloured by their recent delivery ratio, drops in red;
- ``series/*``: altitude, speed, battery, link quality per vehicle, real-time factor;
- ``map/vehicles``: latitude and longitude for the map view (needs map tiles, i.e. a network; the 3D
  view needs nothing);
- ``events``: the run's events (pause, crash, ...) as a text log.
"""

from __future__ import annotations

import bisect
import logging
import math
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from harness.core.clock import NS_PER_S, WALL, Clock
from harness.core.geo import WGS84_A_M, flat_offset_m
from harness.record.links import LinkTracker, ratio_color
from harness.record.sample import VehicleSample, WorldEvent

if TYPE_CHECKING:
    from harness.autopilot.api import MissionItem
    from harness.autopilot.services import System

log = logging.getLogger(__name__)

BODY_SCALE = 4.0
"""Vehicles are drawn this many times their real size (arm 0.25 m): visible when the view holds a swarm."""
TRAIL_DT_S = 0.2
"""One trail point per this much sim time."""
VIEW_STEP_S = 1.0
"""Trails and radio links are logged once per this much sim time."""
MODE_DT_S = 0.2
"""The autopilots' flight mode and armed state (the vehicles' labels) are sampled this often in sim time, as
the run records: a batch can span seconds of sim in a fast run, and a mode must not slip between two."""
PALETTE: tuple[tuple[int, int, int], ...] = (
    (255, 120, 0),  # orange
    (230, 30, 200),  # magenta
    (0, 200, 255),  # cyan
    (250, 225, 0),  # yellow
    (120, 90, 255),  # violet
    (0, 220, 120),  # green
    (255, 60, 60),  # red
    (255, 170, 200),  # pink
)


def vehicle_color(i: int) -> tuple[int, int, int]:
    return PALETTE[i % len(PALETTE)]


def to_ned(lat_deg: float, lon_deg: float, origin: tuple[float, float, float]) -> tuple[float, float]:
    """North and east metres of a latitude / longitude from the world origin (flat earth, as the FDM's)."""
    lat0, lon0, _ = origin
    return flat_offset_m(lat0, lon0, lat_deg, lon_deg, WGS84_A_M)


class _Buffer:
    """One batch of vehicle samples (rows = record instants, all vehicles per row)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.clear()

    def clear(self) -> None:
        self.t_s: list[float] = []
        self.pos: list[list[tuple[float, float, float]]] = []
        self.quat_xyzw: list[list[tuple[float, float, float, float]]] = []
        self.vel: list[list[tuple[float, float, float]]] = []
        self.latlon: list[list[tuple[float, float]]] = []
        self._row: dict[int, tuple[Any, ...]] = {}
        self._row_t: float | None = None
        self.tick_t_s: list[float] = []
        self.rtf: list[float] = []

    def add(self, t_s: float, vehicle: int, sample: tuple[Any, ...]) -> None:
        if self._row_t is not None and t_s != self._row_t:
            self.close_row()
        self._row_t = t_s
        self._row[vehicle] = sample
        if len(self._row) == self.n:
            self.close_row()

    def close_row(self) -> None:
        if self._row_t is None:
            return
        if len(self._row) == self.n:  # a partial row (never in the launcher) is dropped, not padded
            rows = [self._row[i] for i in range(self.n)]
            self.t_s.append(self._row_t)
            self.pos.append([r[0] for r in rows])
            self.quat_xyzw.append([r[1] for r in rows])
            self.vel.append([r[2] for r in rows])
            self.latlon.append([r[3] for r in rows])
        self._row, self._row_t = {}, None

    def span_s(self) -> float:
        return self.t_s[-1] - self.t_s[0] if len(self.t_s) > 1 else 0.0


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
        self._buf = _Buffer(n_vehicles)
        self._last_flush_wall = clock.now_ns()
        self._trail: list[np.ndarray] = []
        """Trail points, one (n, 3) array of every vehicle's position per TRAIL_DT_S, oldest first."""
        self._trail_t: list[float] = []
        self._last_step_s: float | None = None
        self._links_shown = (False, False)
        self._spawned = False
        self._aps: Mapping[int, System] = {}
        self._ap_seen: dict[tuple[str, int], Any] = {}
        self._mode_t: float | None = None
        self._labels: list[tuple[float, int, str]] = []
        """Label changes (sim time, vehicle, text) sampled since the last batch."""
        self._battery: list[float] = [math.nan] * n_vehicles
        self._status: dict[int, int] = {}
        """The last END-TICK-AC status of each vehicle whose autopilot is not in this process (its label)."""
        self._links = LinkTracker()
        self._events_file: Any = None
        self._events_rest = b""
        self._static()

    # -- the WorldSink interface --------------------------------------------------------------------------

    def vehicle(self, s: VehicleSample) -> None:
        w, x, y, z = s.quat_wxyz
        self._buf.add(s.t_ns / NS_PER_S, s.vehicle, (s.pos_ned_m, (x, y, z, w), s.vel_ned_m_s, (s.lat_deg, s.lon_deg)))
        if s.status and s.vehicle not in self._aps:
            self._status[s.vehicle] = s.status

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
        if b.tick_t_s:
            rr = self._rr
            self._rec.send_columns(
                "series/real_time_factor",
                indexes=[rr.TimeColumn("sim_time", duration=np.asarray(b.tick_t_s))],
                columns=rr.Scalars.columns(scalars=np.asarray(b.rtf)),
            )
        for t_s, i, label in self._labels:
            self._rec.set_time("sim_time", duration=t_s)
            self._rec.log(f"world/vehicle/{i}/body", self._rr.Boxes3D.from_fields(labels=[label]))
        self._labels.clear()
        if b.t_s:
            now_s = b.t_s[-1]
            self._rec.set_time("sim_time", duration=now_s)
            self._poll_autopilots()
        b.clear()

    def _sample_labels(self, t_s: float) -> None:
        """Each vehicle's name, flight mode and armed state now, kept when it changed (logged with the batch)."""
        for i, ap in sorted(self._aps.items()):
            try:
                st = ap.telemetry.state()
            except Exception as exc:  # the view must never end a run
                log.debug("view: autopilot %d not readable: %r", i, exc)
                continue
            self._label(t_s, i, st.mode.name, st.armed)
        if self._status:
            from harness.autopilot.api import FlightMode
            from harness.wire.protocol import unpack_status

            for i, status in sorted(self._status.items()):  # flown in another process: mode from its status
                armed, _, main, sub = unpack_status(status)
                mode = FlightMode.from_px4(main, sub)
                self._label(t_s, i, mode.name if mode is not None else f"mode {main}.{sub}", armed)

    def _label(self, t_s: float, vehicle: int, mode: str, armed: bool) -> None:
        """Vehicle ``vehicle``'s label now (name, mode, armed), kept when it changed."""
        label = f"vehicle {vehicle} {mode}{' armed' if armed else ''}"
        if self._changed(("label", vehicle), label):
            self._labels.append((t_s, vehicle, label))

    def _send_vehicles(self, b: _Buffer) -> None:
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
        # trails (a point per TRAIL_DT_S) and radio links: a state every view_step_s of sim time
        self._read_events()
        for j, t in enumerate(b.t_s):
            if not self._trail_t or t - self._trail_t[-1] >= TRAIL_DT_S - 1e-9:
                self._trail_t.append(t)
                self._trail.append(pos[j])
            if self._last_step_s is None or t - self._last_step_s >= self.view_step_s - 1e-9:
                self._last_step_s = t
                self._view_step(t, pos[j])
        if not self._spawned:
            self._spawned = True
            rec.set_time("sim_time", duration=b.t_s[0])  # the name from the start; the sampled modes follow
            for i in range(n):
                first = next((label for _, j, label in self._labels if j == i), f"vehicle {i}")  # with its mode
                rec.log(f"world/vehicle/{i}/body", rr.Boxes3D.from_fields(labels=[first], show_labels=True))
            rec.log(
                "world/spawn",
                rr.Points3D(
                    pos[0],
                    colors=[vehicle_color(i) for i in range(n)],
                    radii=0.3,
                ),
                static=True,
            )

    def _poll_autopilots(self) -> None:
        if not self._aps:
            return
        from harness.autopilot.api import MissionKind

        rr = self._rr
        rec = self._rec
        homes: dict[int, tuple[float, float, float]] = {}
        battery_changed = False
        for i, ap in sorted(self._aps.items()):
            try:
                st = ap.telemetry.state()
                mission = ap.mission.download(MissionKind.MISSION)
                fence = ap.mission.download(MissionKind.FENCE)
                max_hor = float(ap.params.get("GF_MAX_HOR_DIST"))
            except Exception as exc:  # the view must never end a run
                log.debug("view: autopilot %d not readable: %r", i, exc)
                continue
            if st.home_ned_m is not None:
                homes[i] = st.home_ned_m
            pct = 100.0 * st.battery.remaining
            if pct != self._battery[i]:
                self._battery[i] = pct
                battery_changed = True
            home_amsl = st.home.alt_amsl_m if st.home is not None else self.origin[2]
            if self._changed(("mission", i), mission):
                pts = self._item_points(mission, home_amsl)
                if pts:
                    rec.log(
                        f"world/mission/{i}",
                        rr.LineStrips3D([pts], colors=[vehicle_color(i)], radii=0.04),
                        rr.Points3D(
                            pts, colors=[vehicle_color(i)], radii=0.25, labels=[str(k) for k in range(len(pts))]
                        ),
                    )
                else:
                    rec.log(f"world/mission/{i}", rr.Clear(recursive=True))
            fence_key = (fence, max_hor, st.home_ned_m)
            if self._changed(("fence", i), fence_key):
                strips = self._fence_strips(fence, max_hor, st.home_ned_m)
                if strips:
                    rec.log(
                        f"world/geofence/{i}",
                        rr.LineStrips3D(strips, colors=[(*vehicle_color(i), 160)], radii=0.06),
                    )
                else:
                    rec.log(f"world/geofence/{i}", rr.Clear(recursive=True))
        if homes and self._changed(("home",), tuple(sorted(homes.items()))):
            idx = sorted(homes)
            rec.log(
                "world/home",
                rr.Points3D(
                    [homes[i] for i in idx],
                    colors=[vehicle_color(i) for i in idx],
                    radii=0.4,
                ),
            )
        if battery_changed:
            rec.log("series/battery_pct", rr.Scalars(self._battery))

    def _changed(self, key: tuple[Any, ...], value: Any) -> bool:
        if key in self._ap_seen and self._ap_seen[key] == value:
            return False
        self._ap_seen[key] = value
        return True

    def _item_points(self, items: tuple[MissionItem, ...], home_amsl_m: float) -> list[tuple[float, float, float]]:
        pts = []
        for it in items:
            if not it.is_global or (it.lat_deg == 0.0 and it.lon_deg == 0.0):
                continue
            north, east = to_ned(it.lat_deg, it.lon_deg, self.origin)
            alt = it.z + home_amsl_m if it.is_relative_alt else it.z
            pts.append((north, east, -(alt - self.origin[2])))
        return pts

    def _fence_strips(
        self, items: tuple[MissionItem, ...], max_hor_m: float, home: tuple[float, float, float] | None
    ) -> list[list[tuple[float, float, float]]]:
        from harness.autopilot.api import MavCmd

        strips: list[list[tuple[float, float, float]]] = []

        def circle(cn: float, ce: float, r: float) -> list[tuple[float, float, float]]:
            return [(cn + r * math.cos(a), ce + r * math.sin(a), 0.0) for a in np.linspace(0, 2 * math.pi, 73)]

        i = 0
        while i < len(items):
            it = items[i]
            if it.command in (MavCmd.NAV_FENCE_POLYGON_VERTEX_INCLUSION, MavCmd.NAV_FENCE_POLYGON_VERTEX_EXCLUSION):
                count = max(int(it.param1), 3)
                ring = [(*to_ned(v.lat_deg, v.lon_deg, self.origin), 0.0) for v in items[i : i + count]]
                strips.append([*ring, ring[0]])
                i += count
                continue
            if it.command in (MavCmd.NAV_FENCE_CIRCLE_INCLUSION, MavCmd.NAV_FENCE_CIRCLE_EXCLUSION):
                strips.append(circle(*to_ned(it.lat_deg, it.lon_deg, self.origin), float(it.param1)))
            i += 1
        if max_hor_m > 0 and home is not None:
            strips.append(circle(home[0], home[1], max_hor_m))
        return strips

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
        self._links.add_lines([line for line in lines if line])

    def _view_step(self, t_s: float, pos_now: np.ndarray) -> None:
        rr = self._rr
        drop = bisect.bisect_right(self._trail_t, t_s - self.trail_s)
        if drop:
            del self._trail_t[:drop], self._trail[:drop]
        trail = np.stack([*self._trail, pos_now])  # (points, n, 3)
        self._rec.set_time("sim_time", duration=t_s)
        self._rec.log(
            "world/trails",
            rr.LineStrips3D(
                [trail[:, i, :] for i in range(self.n)],
                colors=[vehicle_color(i) for i in range(self.n)],
                radii=0.08,
            ),
        )
        self._links_at(t_s, [tuple(p) for p in pos_now.tolist()])

    def _links_at(self, now_s: float, pos: list[tuple[float, float, float]]) -> None:
        rr = self._rr
        rec = self._rec
        quality = [q for q in self._links.quality(now_s) if max(q.pair) < self.n]
        drops = [d for d in self._links.pop_drops(now_s) if d.dst < self.n and d.src < self.n]
        shown = (bool(quality), bool(drops))
        if not any(shown) and not any(self._links_shown):
            return  # nothing to show and nothing to clear (a run without radio logs nothing here)
        self._links_shown = shown
        rec.log(
            "world/links",
            rr.LineStrips3D(
                [[pos[q.pair[0]], pos[q.pair[1]]] for q in quality],
                colors=[ratio_color(q.ratio) for q in quality],
                radii=0.05,
                labels=[f"{100 * q.ratio:.0f}%" for q in quality],
            ),
        )
        rec.log(
            "world/drops",
            rr.Points3D(
                [pos[d.dst] for d in drops],
                colors=[(255, 0, 0)] * len(drops),
                radii=0.6,
            ),
        )
        if quality:
            per_vehicle = []
            for i in range(self.n):
                mine = [q for q in quality if i in q.pair]
                delivered = sum(q.delivered for q in mine)
                total = delivered + sum(q.dropped for q in mine)
                per_vehicle.append(100.0 * delivered / total if total else math.nan)
            rec.log("series/link_delivery_pct", rr.Scalars(per_vehicle))
