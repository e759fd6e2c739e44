"""What ``world.rrd`` holds beyond poses, fed as the launcher feeds it: radio links coloured by their
delivery ratio and drops (from ``network-events.jsonl``), and the mission and geofence a real autopilot
holds (``Autopilot`` objects, as in-process autopilots are)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from harness.autopilot.api import MavCmd, MavFrame, MissionItem, MissionKind
from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.core.geo import WGS84_A_M, flat_point
from harness.record.links import ratio_color
from harness.record.sample import VehicleSample
from harness.record.scene import to_ned
from tests.record.test_rrd import read_rrd

pytest.importorskip("rerun", reason="the view extra is not installed (pip install 'uav-harness[view]')")

ORIGIN = (47.397742, 8.545594, 488.0)


def latlon(north_m: float, east_m: float) -> tuple[float, float]:
    lat0, lon0, _ = ORIGIN
    return flat_point(lat0, lon0, north_m, east_m, WGS84_A_M)


def test_links_drops_mission_and_geofence_are_recorded(tmp_path: Path) -> None:
    from harness.record.rrd import RrdRecorder

    events = tmp_path / "network-events.jsonl"
    lines = []
    for k in range(20):  # 0 <-> 1: 20 attempts in 2 s, every 4th dropped; 1 <-> 2: all delivered
        t = 0.1 * (k + 1)  # 0.1 .. 2.0 s: all inside the window at 2 s
        lines.append({"t_s": t, "kind": "drop" if k % 4 == 0 else "deliver", "src": 0, "dst": 1, "cause": "snr"})
        lines.append({"t_s": t, "kind": "deliver", "src": 2, "dst": 1, "rssi_dbm": -60.0})
    events.write_text("".join(json.dumps(e) + "\n" for e in lines))
    ap = Autopilot(AutopilotConfig(vehicle=0))
    wps = [latlon(0.0, 0.0), latlon(30.0, 0.0), latlon(30.0, 20.0)]
    mission = [
        MissionItem(
            k, MavFrame.GLOBAL_RELATIVE_ALT_INT, MavCmd.NAV_WAYPOINT, x=round(la * 1e7), y=round(lo * 1e7), z=10
        )
        for k, (la, lo) in enumerate(wps)
    ]
    assert ap.mission.upload(mission).ok
    corners = [latlon(n, e) for n, e in ((-40, -40), (40, -40), (40, 40), (-40, 40))]
    fence = [
        MissionItem(
            k,
            MavFrame.GLOBAL_INT,
            MavCmd.NAV_FENCE_POLYGON_VERTEX_INCLUSION,
            param1=4,
            x=round(la * 1e7),
            y=round(lo * 1e7),
            mission_type=MissionKind.FENCE,
        )
        for k, (la, lo) in enumerate(corners)
    ]
    assert ap.mission.upload(fence, MissionKind.FENCE).ok

    rec = RrdRecorder(tmp_path / "world.rrd", 3, ORIGIN, events_path=events, min_wall_s=0.0)
    rec.attach_autopilots({0: ap})
    for k in range(101):  # 2 s at 50 Hz, three vehicles 10 m apart
        t_ns = k * 20_000_000
        for i in range(3):
            rec.vehicle(
                VehicleSample(
                    t_ns, i, (0.0, 10.0 * i, -5.0), (1.0, 0, 0, 0), (0, 0, 0), 0, 0, 0, (0,) * 4, False, False
                )
            )
        rec.tick(t_ns, 5 * k, t_ns / 1e9 / 10, 10.0)
    rec.close()

    rrd = read_rrd(tmp_path / "world.rrd")
    last = -1  # the state at 2 s: both pairs in the 2 s window
    assert rrd["/world/links"]["sim_time"][last] == pytest.approx(2.0)
    strips = rrd["/world/links"]["LineStrips3D:strips"][last]
    labels = rrd["/world/links"]["LineStrips3D:labels"][last]
    colors = rrd["/world/links"]["LineStrips3D:colors"][last]
    assert labels == ["75%", "100%"]  # pair (0, 1): 15 of 20; pair (1, 2): all
    assert [[tuple(p) for p in s] for s in strips] == [[(0, 0, -5), (0, 10, -5)], [(0, 10, -5), (0, 20, -5)]]
    r, g, b = ratio_color(0.75)
    assert colors[0] == (r << 24) | (g << 16) | (b << 8) | 0xFF  # packed RGBA
    drops = [p for row in rrd["/world/drops"]["Points3D:positions"] for p in row]
    assert len(drops) == 5 and all(tuple(p) == (0, 10, -5) for p in drops)  # at the receiver, vehicle 1
    pts = rrd["/world/mission/0"]["Points3D:positions"][-1]
    assert [tuple(round(c, 1) for c in p) for p in pts] == [(0, 0, -10), (30, 0, -10), (30, 20, -10)]
    ring = rrd["/world/geofence/0"]["LineStrips3D:strips"][-1][0]
    assert len(ring) == 5 and tuple(round(c, 1) for c in ring[1]) == (40.0, -40.0, 0.0)
    assert to_ned(*latlon(30.0, 20.0), ORIGIN) == pytest.approx((30.0, 20.0))
