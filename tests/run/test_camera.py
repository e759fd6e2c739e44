"""The camera as PX4 SITL's simulated MAVLink camera presents it (issue 34): a survey with a trigger distance, the
geotags against the ground truth, MAVSDK's camera plugin in both APIs, and MAVSDK-Python's winch example."""

from __future__ import annotations

import bisect
import itertools
import json
import math
import os
import subprocess
from pathlib import Path

import pytest
from pymavlink import mavutil

from harness.fdm.environment import WorldOrigin
from harness.pytest_plugin import RunRecord
from harness.scenario.sitl_defaults import PX4_HOME

pytestmark = pytest.mark.sim

HERE = Path(__file__).resolve().parent
MIRROR = Path(os.environ.get("MAVSDK_PYTHON_MIRROR", "/work/.mirror/mavlink+MAVSDK-Python/repo"))


def truth_at(track: list[dict], t_s: float) -> tuple[float, float, float]:
    """The ground-truth position at ``t_s``, linear between the recorded samples (50 Hz)."""
    times = [s["t_s"] for s in track]
    i = min(max(1, bisect.bisect_left(times, t_s)), len(times) - 1)
    (t0, p0), (t1, p1) = (times[i - 1], track[i - 1]["pos_ned_m"]), (times[i], track[i]["pos_ned_m"])
    f = 0.0 if t1 == t0 else (t_s - t0) / (t1 - t0)
    return (p0[0] + f * (p1[0] - p0[0]), p0[1] + f * (p1[1] - p0[1]), p0[2] + f * (p1[2] - p0[2]))


def test_survey_with_a_trigger_distance_gives_geotagged_captures(harness_run) -> None:  # type: ignore[no-untyped-def]
    dist = 10.0
    run: RunRecord = harness_run(mission=HERE / "camera_survey_mission.py", duration_s=300, args=[str(dist)])
    assert run.ok, run.message
    out = run.mission_output(0)
    assert "CAMERA 100 sim survey camera" in out, out
    caps = [json.loads(line[len("CAPTURED ") :]) for line in out.splitlines() if line.startswith("CAPTURED ")]
    origin = WorldOrigin(*PX4_HOME)
    track = run.vehicle(0).track
    worst = 0.0
    pts = []
    for c in caps:
        assert c["compid"] == 100 and c["file_url"] == f"sim://camera/IMG_{c['image_index']:05d}.jpg"
        n, e, d = origin.geodetic_to_ned(c["lat"] / 1e7, c["lon"] / 1e7, c["alt"] / 1000)
        tn, te, td = truth_at(track, c["time_boot_ms"] / 1000)
        worst = max(worst, math.dist((n, e, d), (tn, te, td)))
        pts.append((n, e))
    spacing = [math.dist(a, b) for a, b in itertools.pairwise(pts)]
    # the path flown while triggering: 100 m north, then 65 m east; a picture at its start and every 10 m
    expected = math.floor(165.0 / dist) + 1
    print(
        f"FIGURE survey DO_SET_CAM_TRIGG_DIST {dist:g} m: {len(caps)} captures (path 165 m: {expected}), spacing "
        f"{min(spacing):.3f}-{max(spacing):.3f} m, worst geotag vs ground truth {worst:.4f} m"
    )
    assert [c["image_index"] for c in caps] == list(range(len(caps)))
    assert len(caps) == expected
    assert all(0.95 * dist <= s <= 1.05 * dist for s in spacing), spacing  # (geotags in 1e-7 deg, 1.1 cm)
    assert worst < 0.1
    events = [e["detail"] for e in run.topics["/sim/events"] if e["kind"] == "capture"]
    assert [e["index"] for e in events] == [c["image_index"] for c in caps]  # recorded, one event each
    assert all(abs(e["lat_deg"] * 1e7 - c["lat"]) <= 1 for e, c in zip(events, caps, strict=True))


@pytest.mark.parametrize("api", ["native", "grpc"])
def test_mavsdk_camera_plugin_takes_a_photo_and_lists_it(harness_run, api: str) -> None:  # type: ignore[no-untyped-def]
    run: RunRecord = harness_run(mission=HERE / f"camera_{api}_mission.py", duration_s=60)
    assert run.ok, run.message
    out = run.mission_output(0)
    assert "CAMERAS [(100, 'sim survey camera')]" in out, out
    photos = [line.split() for line in out.splitlines() if line.startswith("PHOTO ")]
    assert len(photos) == 1 and photos[0][1] == "0" and photos[0][4] == "sim://camera/IMG_00000.jpg", out
    assert abs(float(photos[0][2]) - PX4_HOME[0]) < 1e-6 and abs(float(photos[0][3]) - PX4_HOME[1]) < 1e-6
    print(f"FIGURE MAVSDK camera ({api}): {out.strip().splitlines()}")


def test_winch_example_gets_its_answer(tmp_path: Path) -> None:
    if not MIRROR.is_dir():
        pytest.skip(f"no MAVSDK-Python mirror at {MIRROR}: its winch example is not run")
    text = subprocess.run(
        ["git", f"--git-dir={MIRROR}", "show", "HEAD:examples/winch.py"], capture_output=True, text=True, check=True
    ).stdout
    (tmp_path / "winch.py").write_text(text)
    out = tmp_path / "run"
    proc = subprocess.run(
        [os.sys.executable, "-m", "harness.cli", "run", "--mission", str(tmp_path / "winch.py"), "--duration", "8",
         "--out", str(out), "--no-progress"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    stdout = (out / "mission-0.stdout").read_text()
    assert "-- Winch action: load payload" in stdout and "Staying connected" in stdout, (stdout, proc.stderr)
    log = mavutil.mavlink_connection(str(out / "vehicle-0.tlog"), dialect="common")
    acks = []
    while (m := log.recv_match(type="COMMAND_ACK")) is not None:
        if m.command == 42600:
            acks.append((m.get_srcComponent(), m.result))
    assert acks == [(169, 0)], acks  # accepted once, from the winch component MAVSDK addressed
