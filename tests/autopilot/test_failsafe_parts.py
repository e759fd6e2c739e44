"""Geofence shapes and the battery model, directly."""

from __future__ import annotations

from harness.autopilot.api import MavFrame, MissionItem
from harness.autopilot.battery import Battery
from harness.autopilot.geofence import Geofence
from harness.autopilot.params import Params
from harness.core.geo import GeoRef

REF = GeoRef(47.0, 8.0, 500.0)


def _to_local(lat: float, lon: float) -> tuple[float, float]:
    n, e, _ = REF.to_ned(lat, lon, 500.0)
    return (n, e)


def _vertex(seq: int, cmd: int, n: float, e: float, count: float = 4.0) -> MissionItem:
    lat, lon, _ = REF.to_geo(n, e, 0.0)
    return MissionItem(seq, MavFrame.GLOBAL_INT, cmd, param1=count, x=lat, y=lon)


def test_polygon_and_circle_fences() -> None:
    fence = Geofence(Params())
    square = [(-50.0, -50.0), (-50.0, 50.0), (50.0, 50.0), (50.0, -50.0)]
    items = [_vertex(i, 5001, n, e) for i, (n, e) in enumerate(square)]
    lat, lon, _ = REF.to_geo(20.0, 20.0, 0.0)
    items.append(MissionItem(4, MavFrame.GLOBAL_INT, 5004, param1=5.0, x=lat, y=lon))  # exclusion circle r=5
    fence.set_items(items)
    home = (0.0, 0.0, 0.0)
    assert fence.breach((10.0, -30.0, -5.0), home, _to_local) == ""
    assert "inclusion" in fence.breach((60.0, 0.0, -5.0), home, _to_local)
    assert "exclusion" in fence.breach((22.0, 19.0, -5.0), home, _to_local)


def test_inclusion_fences_are_a_union_as_in_px4() -> None:
    """Inside one of two inclusion areas is allowed; outside all of them is a breach."""
    fence = Geofence(Params())
    square = [(-50.0, -50.0), (-50.0, 50.0), (50.0, 50.0), (50.0, -50.0)]
    items = [_vertex(i, 5001, n, e) for i, (n, e) in enumerate(square)]
    lat, lon, _ = REF.to_geo(200.0, 0.0, 0.0)
    items.append(MissionItem(4, MavFrame.GLOBAL_INT, 5003, param1=30.0, x=lat, y=lon))  # inclusion circle far away
    fence.set_items(items)
    home = (0.0, 0.0, 0.0)
    assert fence.breach((10.0, -30.0, -5.0), home, _to_local) == ""  # in the square, not in the circle
    assert fence.breach((210.0, 5.0, -5.0), home, _to_local) == ""  # in the circle, not in the square
    assert "outside every inclusion fence" in fence.breach((120.0, 0.0, -5.0), home, _to_local)


def test_distance_and_height_limits() -> None:
    params = Params(overrides={"GF_MAX_HOR_DIST": 100.0, "GF_MAX_VER_DIST": 30.0})
    fence = Geofence(params)
    assert fence.breach((60.0, 60.0, -10.0), (0.0, 0.0, 0.0), None) == ""
    assert "GF_MAX_HOR_DIST" in fence.breach((90.0, 60.0, -10.0), (0.0, 0.0, 0.0), None)
    assert "GF_MAX_VER_DIST" in fence.breach((0.0, 0.0, -31.0), (0.0, 0.0, 0.0), None)


def test_battery_drains_with_power_and_sags_under_load() -> None:
    params = Params()
    bat = Battery(params)
    full_v = bat.voltage_v
    bat.update((0.72, 0.72, 0.72, 0.72), True, 0.01)
    loaded_v, hover_a = bat.voltage_v, bat.current_a
    assert loaded_v < full_v and 5.0 < hover_a < 30.0
    bat.update((1.0, 1.0, 1.0, 1.0), True, 0.01)
    assert bat.current_a > 2.0 * hover_a and bat.voltage_v < loaded_v
    # ten minutes of hover uses a sensible share of a 5 Ah pack
    before = bat.remaining
    for _ in range(600):
        bat.update((0.72, 0.72, 0.72, 0.72), True, 1.0)
    assert 0.3 < before - bat.remaining < 0.9
    idle = Battery(params)
    idle.update((0.72,) * 4, False, 60.0)
    assert idle.remaining > 0.99
