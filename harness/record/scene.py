"""The 3D view as a model: what the scene of ``world.rrd`` shows, without Rerun.

State goes in — batches of vehicle samples (:class:`SampleBatch`), what the autopilots hold
(:class:`AutopilotReadout`), the network's events — and scene updates come out: typed values
(:class:`Trails`, :class:`Links`, :class:`MissionPath`, :class:`FenceLines`, :class:`Homes`, ...) that say
what changed, nothing when nothing did. :class:`~harness.record.rrd.RrdRecorder` is the thin writer that
turns them into Rerun calls; tests read the model directly.

The scene is in the world frame, NED (x north, y east, z down) from the world origin.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from harness.autopilot.api import MavCmd, MissionItem
from harness.core.geo import WGS84_A_M, Vec3, flat_offset_m
from harness.record.links import LinkTracker, ratio_color

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

Color = tuple[int, ...]

CAMERA_HFOV_DEG = 60.0
CAMERA_ASPECT = 4.0 / 3.0
"""The frustum drawn for a vehicle's gimbal camera (a drawing: the simulated gimbal carries no camera)."""


def camera_frustum(depth_m: float = 0.6 * BODY_SCALE) -> list[list[Vec3]]:
    """A camera's frustum in its own frame (x along the optical axis, y right, z down, as the world's NED):
    the four edges from the lens, then the closed far rectangle at ``depth_m``."""
    half_w = depth_m * math.tan(math.radians(CAMERA_HFOV_DEG) / 2)
    half_h = half_w / CAMERA_ASPECT
    corners: list[Vec3] = [
        (depth_m, -half_w, -half_h),
        (depth_m, half_w, -half_h),
        (depth_m, half_w, half_h),
        (depth_m, -half_w, half_h),
    ]
    return [*([(0.0, 0.0, 0.0), c] for c in corners), [*corners, corners[0]]]


def vehicle_color(i: int) -> tuple[int, int, int]:
    return PALETTE[i % len(PALETTE)]


def to_ned(lat_deg: float, lon_deg: float, origin: tuple[float, float, float]) -> tuple[float, float]:
    """North and east metres of a latitude / longitude from the world origin (flat earth, as the FDM's)."""
    lat0, lon0, _ = origin
    return flat_offset_m(lat0, lon0, lat_deg, lon_deg, WGS84_A_M)


class SampleBatch:
    """One batch of vehicle samples (rows = record instants, all vehicles per row), and the ticks' timing."""

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


@dataclass(frozen=True)
class AutopilotReadout:
    """What the view shows of one autopilot (``harness.autopilot.services.System``), read at a batch."""

    battery_pct: float
    home_amsl_m: float | None
    home_ned_m: Vec3 | None
    mission: tuple[MissionItem, ...]
    fence: tuple[MissionItem, ...]
    fence_max_hor_m: float
    """The horizontal distance limit from home (0: none)."""


# -- scene updates ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Spawn:
    """Where the vehicles were at the first sample, and each one's first label, from that time on."""

    t_s: float
    points: np.ndarray
    labels: tuple[str, ...]


@dataclass(frozen=True)
class Trails:
    """The last ``trail_s`` of each vehicle's path (one strip per vehicle) at ``t_s``."""

    t_s: float
    strips: tuple[np.ndarray, ...]


@dataclass(frozen=True)
class Links:
    """Radio links coloured by delivery ratio and the drops since the last, at ``t_s``; ``per_vehicle_pct``
    (None when no link was used) is each vehicle's delivery ratio."""

    t_s: float
    lines: tuple[tuple[Vec3, Vec3], ...]
    colors: tuple[Color, ...]
    labels: tuple[str, ...]
    drops: tuple[Vec3, ...]
    per_vehicle_pct: tuple[float, ...] | None


@dataclass(frozen=True)
class Label:
    """A vehicle's label (name, mode, armed) from ``t_s`` on."""

    t_s: float
    vehicle: int
    text: str


@dataclass(frozen=True)
class MissionPath:
    """The mission a vehicle holds, as points (empty: none, clear it)."""

    vehicle: int
    points: tuple[Vec3, ...]


@dataclass(frozen=True)
class FenceLines:
    """A vehicle's geofence as closed strips on the ground (empty: none, clear it)."""

    vehicle: int
    strips: tuple[tuple[Vec3, ...], ...]


@dataclass(frozen=True)
class Homes:
    vehicles: tuple[int, ...]
    points: tuple[Vec3, ...]


@dataclass(frozen=True)
class Battery:
    """Every vehicle's battery in percent (NaN: unknown)."""

    pct: tuple[float, ...]


Update = Spawn | Trails | Links | Label | MissionPath | FenceLines | Homes | Battery


class Scene:
    """The view's state: trails, links, labels and what each autopilot showed last (to send changes only)."""

    def __init__(self, n: int, origin: tuple[float, float, float], trail_s: float, view_step_s: float) -> None:
        self.n = n
        self.origin = origin
        self.trail_s = trail_s
        self.view_step_s = view_step_s
        self.links = LinkTracker()
        self._trail: list[np.ndarray] = []
        """Trail points, one (n, 3) array of every vehicle's position per TRAIL_DT_S, oldest first."""
        self._trail_t: list[float] = []
        self._last_step_s: float | None = None
        self._links_shown = (False, False)
        self._spawned = False
        self._seen: dict[tuple[Any, ...], Any] = {}
        self._battery: list[float] = [math.nan] * n

    def changed(self, key: tuple[Any, ...], value: Any) -> bool:
        """Whether ``value`` differs from the last one given for ``key`` (and remember it)."""
        if key in self._seen and self._seen[key] == value:
            return False
        self._seen[key] = value
        return True

    def label(self, t_s: float, vehicle: int, mode: str, armed: bool) -> Label | None:
        """Vehicle ``vehicle``'s label now (name, mode, armed), when it changed."""
        text = f"vehicle {vehicle} {mode}{' armed' if armed else ''}"
        return Label(t_s, vehicle, text) if self.changed(("label", vehicle), text) else None

    def batch(self, t_s: list[float], pos: np.ndarray, labels: list[Label]) -> list[Update]:
        """A batch of poses (``pos``: (rows, n, 3) at ``t_s``): trails and links every ``view_step_s``, and the
        spawn points with the first batch (``labels``: the labels sampled with it)."""
        out: list[Update] = []
        for j, t in enumerate(t_s):
            if not self._trail_t or t - self._trail_t[-1] >= TRAIL_DT_S - 1e-9:
                self._trail_t.append(t)
                self._trail.append(pos[j])
            if self._last_step_s is None or t - self._last_step_s >= self.view_step_s - 1e-9:
                self._last_step_s = t
                out.append(self._trails(t, pos[j]))
                links = self._links_at(t, [tuple(p) for p in pos[j].tolist()])
                if links is not None:
                    out.append(links)
        if not self._spawned:
            self._spawned = True
            first = tuple(
                next((lb.text for lb in labels if lb.vehicle == i), f"vehicle {i}") for i in range(self.n)
            )  # the name from the start, with its mode; the sampled modes follow
            out.append(Spawn(t_s[0], pos[0], first))
        return out

    def _trails(self, t_s: float, pos_now: np.ndarray) -> Trails:
        drop = bisect.bisect_right(self._trail_t, t_s - self.trail_s)
        if drop:
            del self._trail_t[:drop], self._trail[:drop]
        trail = np.stack([*self._trail, pos_now])  # (points, n, 3)
        return Trails(t_s, tuple(trail[:, i, :] for i in range(self.n)))

    def _links_at(self, now_s: float, pos: list[tuple[float, ...]]) -> Links | None:
        quality = [q for q in self.links.quality(now_s) if max(q.pair) < self.n]
        drops = [d for d in self.links.pop_drops(now_s) if d.dst < self.n and d.src < self.n]
        shown = (bool(quality), bool(drops))
        if not any(shown) and not any(self._links_shown):
            return None  # nothing to show and nothing to clear (a run without radio logs nothing here)
        self._links_shown = shown
        per_vehicle: tuple[float, ...] | None = None
        if quality:
            pct = []
            for i in range(self.n):
                mine = [q for q in quality if i in q.pair]
                delivered = sum(q.delivered for q in mine)
                total = delivered + sum(q.dropped for q in mine)
                pct.append(100.0 * delivered / total if total else math.nan)
            per_vehicle = tuple(pct)
        return Links(
            now_s,
            tuple((_vec(pos[q.pair[0]]), _vec(pos[q.pair[1]])) for q in quality),
            tuple(ratio_color(q.ratio) for q in quality),
            tuple(f"{100 * q.ratio:.0f}%" for q in quality),
            tuple(_vec(pos[d.dst]) for d in drops),
            per_vehicle,
        )

    def autopilots(self, readouts: Mapping[int, AutopilotReadout]) -> list[Update]:
        """What the autopilots hold now: the missions, fences, homes and batteries that changed."""
        out: list[Update] = []
        homes: dict[int, Vec3] = {}
        battery_changed = False
        for i, r in sorted(readouts.items()):
            if r.home_ned_m is not None:
                homes[i] = r.home_ned_m
            if r.battery_pct != self._battery[i]:
                self._battery[i] = r.battery_pct
                battery_changed = True
            home_amsl = r.home_amsl_m if r.home_amsl_m is not None else self.origin[2]
            if self.changed(("mission", i), r.mission):
                out.append(MissionPath(i, tuple(self._item_points(r.mission, home_amsl))))
            if self.changed(("fence", i), (r.fence, r.fence_max_hor_m, r.home_ned_m)):
                strips = self._fence_strips(r.fence, r.fence_max_hor_m, r.home_ned_m)
                out.append(FenceLines(i, tuple(tuple(s) for s in strips)))
        if homes and self.changed(("home",), tuple(sorted(homes.items()))):
            idx = tuple(sorted(homes))
            out.append(Homes(idx, tuple(homes[i] for i in idx)))
        if battery_changed:
            out.append(Battery(tuple(self._battery)))
        return out

    def _item_points(self, items: tuple[MissionItem, ...], home_amsl_m: float) -> list[Vec3]:
        pts = []
        for it in items:
            if not it.is_global or (it.lat_deg == 0.0 and it.lon_deg == 0.0):
                continue
            north, east = to_ned(it.lat_deg, it.lon_deg, self.origin)
            alt = it.z + home_amsl_m if it.is_relative_alt else it.z
            pts.append((north, east, -(alt - self.origin[2])))
        return pts

    def _fence_strips(self, items: tuple[MissionItem, ...], max_hor_m: float, home: Vec3 | None) -> list[list[Vec3]]:
        strips: list[list[Vec3]] = []

        def circle(cn: float, ce: float, r: float) -> list[Vec3]:
            return [(cn + r * math.cos(a), ce + r * math.sin(a), 0.0) for a in np.linspace(0, 2 * math.pi, 73)]

        i = 0
        while i < len(items):
            it = items[i]
            if it.command in (MavCmd.NAV_FENCE_POLYGON_VERTEX_INCLUSION, MavCmd.NAV_FENCE_POLYGON_VERTEX_EXCLUSION):
                count = max(int(it.param1), 3)
                ring: list[Vec3] = [(*to_ned(v.lat_deg, v.lon_deg, self.origin), 0.0) for v in items[i : i + count]]
                strips.append([*ring, ring[0]])
                i += count
                continue
            if it.command in (MavCmd.NAV_FENCE_CIRCLE_INCLUSION, MavCmd.NAV_FENCE_CIRCLE_EXCLUSION):
                strips.append(circle(*to_ned(it.lat_deg, it.lon_deg, self.origin), float(it.param1)))
            i += 1
        if max_hor_m > 0 and home is not None:
            strips.append(circle(home[0], home[1], max_hor_m))
        return strips


def _vec(p: tuple[float, ...]) -> Vec3:
    return (p[0], p[1], p[2])
