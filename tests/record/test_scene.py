"""The 3D view's scene model without Rerun: poses in, trails / spawn / labels out at the view's pace; the
autopilots' missions, fences, homes and batteries out when, and only when, they change."""

from __future__ import annotations

import math

import numpy as np

from harness.autopilot.api import MavCmd, MavFrame, MissionItem
from harness.core.geo import WGS84_A_M, flat_point
from harness.record.scene import (
    AutopilotReadout,
    Battery,
    FenceLines,
    Homes,
    MissionPath,
    Scene,
    Spawn,
    Trails,
)

ORIGIN = (47.397742, 8.545594, 488.0)


def _latlon_int(north_m: float, east_m: float) -> tuple[int, int]:
    lat, lon = flat_point(ORIGIN[0], ORIGIN[1], north_m, east_m, WGS84_A_M)
    return round(lat * 1e7), round(lon * 1e7)


def _poses(t_s: list[float], n: int) -> np.ndarray:
    """Vehicle i at (t, i, -1) m: north grows with time."""
    return np.array([[(t, float(i), -1.0) for i in range(n)] for t in t_s])


def test_trails_every_view_step_spawn_once_with_the_first_labels() -> None:
    scene = Scene(2, ORIGIN, trail_s=1.0, view_step_s=0.5)
    label = scene.label(0.0, 1, "HOLD", armed=False)
    assert label is not None and label.text == "vehicle 1 HOLD"
    assert scene.label(0.1, 1, "HOLD", armed=False) is None  # unchanged: nothing to send
    t = [0.0, 0.2, 0.4, 0.6]
    out = scene.batch(t, _poses(t, 2), [label])
    trails = [u for u in out if isinstance(u, Trails)]
    assert [u.t_s for u in trails] == [0.0, 0.6]
    spawn = [u for u in out if isinstance(u, Spawn)]
    assert len(spawn) == 1 and spawn[0].labels == ("vehicle 0", "vehicle 1 HOLD")
    assert spawn[0].points.tolist() == [[0.0, 0.0, -1.0], [0.0, 1.0, -1.0]]
    t = [0.8, 1.0, 1.2, 1.8]
    later = scene.batch(t, _poses(t, 2), [])
    assert not any(isinstance(u, Spawn) for u in later)
    last = [u for u in later if isinstance(u, Trails)][-1]
    assert last.t_s == 1.8 and last.strips[1][:, 0].min() >= 0.8 - 1e-9  # older than trail_s: dropped
    assert last.strips[1][-1].tolist() == [1.8, 1.0, -1.0]


def _readout(mission: tuple[MissionItem, ...] = (), battery: float = 100.0, radius: float = 0.0) -> AutopilotReadout:
    return AutopilotReadout(battery, ORIGIN[2], (0.0, 0.0, 0.0), mission, (), radius)


def test_autopilot_changes_only() -> None:
    scene = Scene(1, ORIGIN, trail_s=30.0, view_step_s=1.0)
    x, y = _latlon_int(30.0, 0.0)
    wp = (MissionItem(0, MavFrame.GLOBAL_RELATIVE_ALT_INT, MavCmd.NAV_WAYPOINT, x=x, y=y, z=10.0),)
    first = scene.autopilots({0: _readout(wp)})
    path = [u for u in first if isinstance(u, MissionPath)]
    assert len(path) == 1 and len(path[0].points) == 1
    north, east, down = path[0].points[0]
    assert math.isclose(north, 30.0, abs_tol=0.01) and abs(east) < 0.01 and math.isclose(down, -10.0)
    assert [type(u) for u in first] == [MissionPath, FenceLines, Homes, Battery]
    assert scene.autopilots({0: _readout(wp)}) == []  # nothing changed: nothing to send
    cleared = scene.autopilots({0: _readout((), battery=50.0)})
    assert MissionPath(0, ()) in cleared and Battery((50.0,)) in cleared


def test_the_distance_limit_is_a_circle_around_home() -> None:
    scene = Scene(1, ORIGIN, trail_s=30.0, view_step_s=1.0)
    fence = [u for u in scene.autopilots({0: _readout(radius=50.0)}) if isinstance(u, FenceLines)]
    (strip,) = fence[0].strips
    assert all(math.isclose(math.hypot(n, e), 50.0) for n, e, _ in strip)
    x, y = _latlon_int(0.0, 0.0)
    circle = MissionItem(0, MavFrame.GLOBAL_INT, MavCmd.NAV_FENCE_CIRCLE_INCLUSION, param1=20.0, x=x, y=y)
    fenced = AutopilotReadout(100.0, ORIGIN[2], (0.0, 0.0, 0.0), (), (circle,), 0.0)
    (update,) = [u for u in scene.autopilots({0: fenced}) if isinstance(u, FenceLines)]
    assert len(update.strips) == 1 and max(math.hypot(n, e) for n, e, _ in update.strips[0]) < 20.01
