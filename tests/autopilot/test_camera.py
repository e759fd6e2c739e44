"""The camera device (``harness.autopilot.camera``): single pictures, a time-lapse, the distance trigger, video, and
the geotag taken from the frame's ground truth at the tick."""

from __future__ import annotations

import itertools
import threading

from harness.autopilot.api import MavCmd, MavFrame, MissionItem
from harness.autopilot.camera import MODE_VIDEO, CameraDevice
from harness.fdm.frame import Truth

MS = 1_000_000


def truth(n: float, e: float = 0.0) -> Truth:
    return Truth((n, e, -20.0), (5.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                 47.0 + n * 1e-5, 8.0, 508.0, False, False)  # fmt: skip


def test_photo_and_time_lapse_on_sim_time() -> None:
    cam = CameraDevice(threading.Lock())
    assert not cam.active
    assert cam.start_capture(0.0, 1).ok and cam.active
    cam.step(4 * MS, truth(1.0), True)
    (c,) = cam.take_new()
    assert (c.index, c.t_ns, c.lat_deg, c.alt_amsl_m, c.pos_ned_m) == (0, 4 * MS, 47.00001, 508.0, (1.0, 0.0, -20.0))
    assert not cam.active  # nothing left to do: no per-tick work
    assert cam.start_capture(0.5, 3).ok
    for k in range(1, 501):  # 2 s of 4 ms ticks
        cam.step(k * 4 * MS, truth(0.0), True)
    assert [x.t_ns for x in cam.take_new()] == [4 * MS, 504 * MS, 1004 * MS] and not cam.active
    assert not cam.start_capture(0.0, 0).ok  # a time-lapse needs an interval
    assert cam.set_mode(MODE_VIDEO).ok and not cam.start_capture(0.0, 1).ok and cam.video(True, 0).ok


def test_distance_trigger_from_the_mission() -> None:
    cam = CameraDevice(threading.Lock())
    item = MissionItem(1, MavFrame.MISSION, MavCmd.DO_SET_CAM_TRIGG_DIST, param1=10.0, param3=1.0)
    cam.mission_item(item, 0)
    for k in range(1000):  # 0.1 m a tick, north
        cam.step(k * 4 * MS, truth(k * 0.1), True)
    norths = [c.pos_ned_m[0] for c in cam.take_new()]
    assert len(norths) == 10 and all(abs(b - a - 10.0) < 0.11 for a, b in itertools.pairwise(norths))
    cam.mission_item(MissionItem(2, MavFrame.MISSION, MavCmd.DO_SET_CAM_TRIGG_DIST, param1=0.0), 0)
    assert not cam.active
