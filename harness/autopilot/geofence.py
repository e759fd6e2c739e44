"""Geofence: distance/height limits from home (``GF_MAX_HOR_DIST``, ``GF_MAX_VER_DIST``) and uploaded fence
items (inclusion/exclusion polygons and circles, MAVLink commands 5001-5004), checked in the local frame.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from harness.autopilot.api import MavCmd, MissionItem
from harness.autopilot.params import Params
from harness.core.geo import Vec3


def _inside_polygon(x: float, y: float, poly: Sequence[tuple[float, float]]) -> bool:
    inside = False
    n = len(poly)
    j = n - 1
    for i in range(n):
        xi, yi = poly[i]
        xj, yj = poly[j]
        if (yi > y) != (yj > y) and x < (xj - xi) * (y - yi) / (yj - yi) + xi:
            inside = not inside
        j = i
    return inside


class Geofence:
    def __init__(self, params: Params) -> None:
        self.params = params
        self.items: tuple[MissionItem, ...] = ()
        self._shapes: list[tuple[bool, list[tuple[float, float]], float]] | None = None
        """(inclusion, polygon vertices or [circle centre], circle radius or -1 for a polygon)."""

    @property
    def max_hor_m(self) -> float:
        """The horizontal distance limit from home (``GF_MAX_HOR_DIST``; 0: none)."""
        return self.params["GF_MAX_HOR_DIST"]

    def set_items(self, items: Sequence[MissionItem]) -> None:
        self.items = tuple(items)
        self._shapes = None

    def _build(
        self, to_local: Callable[[float, float], tuple[float, float]]
    ) -> list[tuple[bool, list[tuple[float, float]], float]]:
        shapes: list[tuple[bool, list[tuple[float, float]], float]] = []
        i = 0
        items = self.items
        while i < len(items):
            it = items[i]
            if it.command in (MavCmd.NAV_FENCE_POLYGON_VERTEX_INCLUSION, MavCmd.NAV_FENCE_POLYGON_VERTEX_EXCLUSION):
                n = max(int(it.param1), 3)
                pts = [to_local(v.lat_deg, v.lon_deg) for v in items[i : i + n]]
                shapes.append((it.command == MavCmd.NAV_FENCE_POLYGON_VERTEX_INCLUSION, pts, -1.0))
                i += n
                continue
            if it.command in (MavCmd.NAV_FENCE_CIRCLE_INCLUSION, MavCmd.NAV_FENCE_CIRCLE_EXCLUSION):
                c = to_local(it.lat_deg, it.lon_deg)
                shapes.append((it.command == MavCmd.NAV_FENCE_CIRCLE_INCLUSION, [c], float(it.param1)))
            i += 1
        return shapes

    def breach(self, pos: Vec3, home: Vec3, to_local: Callable[[float, float], tuple[float, float]] | None) -> str:
        """'' when inside, else a description of the breach."""
        p = self.params
        hmax, vmax = p["GF_MAX_HOR_DIST"], p["GF_MAX_VER_DIST"]
        dh = math.hypot(pos[0] - home[0], pos[1] - home[1])
        if hmax > 0 and dh > hmax:
            return f"{dh:.0f} m from home, limit GF_MAX_HOR_DIST {hmax:.0f} m"
        h = home[2] - pos[2]
        if vmax > 0 and h > vmax:
            return f"{h:.0f} m above home, limit GF_MAX_VER_DIST {vmax:.0f} m"
        if not self.items or to_local is None:
            return ""
        if self._shapes is None:
            self._shapes = self._build(to_local)
        # PX4's rule: the allowed area is the union of the inclusion fences (if there are any) minus every
        # exclusion fence; a vehicle inside one of two overlapping inclusion areas is not in breach
        x, y = pos[0], pos[1]
        had_inclusion = in_inclusion = False
        for inclusion, pts, r in self._shapes:
            if r < 0:
                inside = _inside_polygon(x, y, pts)
            else:
                inside = math.hypot(x - pts[0][0], y - pts[0][1]) <= r
            if inclusion:
                had_inclusion = True
                in_inclusion = in_inclusion or inside
            elif inside:
                return "inside an exclusion fence"
        if had_inclusion and not in_inclusion:
            return "outside every inclusion fence"
        return ""
