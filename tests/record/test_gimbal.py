"""The gimbal's attitude in the recordings: a pymavlink ground station (``gimbal_mission.py``) points the gimbals
of a run with MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW at set sim times, and world.mcap and world.rrd show them
follow each command from the tick it was handled, at the device's 90 deg/s — for a vehicle whose autopilot is
in the root process and one flown and simulated by an autopilot host alike, the same with one worker or two.
An ArduCopter vehicle (no gimbal) refuses and records nothing extra."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from harness.record.world import read_topics

pytestmark = pytest.mark.sim
pytest.importorskip("rerun", reason="the view extra is not installed (pip install 'uav-harness[view]')")

from tests.record.test_rrd import read_rrd  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SLEW_DEG_S = 90.0


def _run(out: Path, workers: int) -> None:
    proc = subprocess.run(
        [
            sys.executable, "-m", "harness.cli", "run", "--vehicles", "3", "--firmware", "px4,px4,ardupilot",
            "--workers", str(workers), "--network", "none", "--seed", "3", "--duration", "12", "--no-progress",
            "--out", str(out), "--mission", str(Path(__file__).with_name("gimbal_mission.py")),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "GIMBAL_NONE": "2"},
        cwd=ROOT,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr


def _expected(t_s: float, sent: list[tuple[float, float, float]]) -> tuple[float, float]:
    """Pitch and yaw at ``t_s``: from (0, 0), each command moves them at most SLEW_DEG_S from its send time."""
    pitch = yaw = 0.0
    for k, (at, p, y) in enumerate(sent):
        if t_s <= at:
            break
        until = sent[k + 1][0] if k + 1 < len(sent) else math.inf
        dt = min(t_s, until) - at
        pitch += max(-SLEW_DEG_S * dt, min(SLEW_DEG_S * dt, p - pitch))
        yaw += max(-SLEW_DEG_S * dt, min(SLEW_DEG_S * dt, y - yaw))
    return pitch, yaw


def _heading_deg(q: dict[str, float]) -> float:
    w, x, y, z = q["w"], q["x"], q["y"], q["z"]
    return math.degrees(math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def _optical_axis(q: dict[str, float]) -> tuple[float, float, float]:
    """The camera's x axis in the world NED frame."""
    w, x, y, z = q["w"], q["x"], q["y"], q["z"]
    return (1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y))


def test_recorded_gimbal_follows_pitchyaw_commands_in_and_across_processes(tmp_path: Path) -> None:
    _run(tmp_path / "w2", workers=2)  # vehicle 0's autopilot in the root, vehicles 1 and 2 in a host
    out = tmp_path / "w2"
    sent = []
    for line in (out / "mission-0.stdout").read_text().splitlines():
        _, p, y, _, _, at, _, result = line.split()
        assert result == "0", line
        sent.append((float(at), float(p), float(y)))
    assert sent == [(3.0, -45.0, 30.0), (5.0, -90.0, -60.0)]
    assert (out / "mission-1.stdout").read_text() == (out / "mission-0.stdout").read_text()
    assert "pitchyaw -45 30 sent at 3.000000 result 3" in (out / "mission-2.stdout").read_text()  # UNSUPPORTED
    mcap = read_topics(out / "world.mcap")
    assert "/vehicle/2/gimbal" not in mcap  # ArduCopter: no gimbal, no topic
    rrd = read_rrd(out / "world.rrd")
    assert not any(e.startswith("/world/gimbal/2") for e in rrd)
    for v in (0, 1):
        gimbal = mcap[f"/vehicle/{v}/gimbal"]
        poses = {round(m["timestamp"]["sec"] * 1e9 + m["timestamp"]["nsec"]): m for m in mcap[f"/vehicle/{v}/pose"]}
        t = [m["t_s"] for m in gimbal]
        # nothing before the first command: the first sample is the first recorded tick after it (50 Hz)
        assert t[0] == pytest.approx(3.02) and t == sorted(t) and t[-1] == pytest.approx(7.0)
        assert len(t) == 200
        for m in gimbal:
            pitch, yaw = _expected(m["t_s"], sent)
            assert m["pitch_deg"] == pytest.approx(pitch, abs=0.002), m
            assert m["yaw_deg"] == pytest.approx(yaw, abs=0.002), m
            assert m["roll_deg"] == 0.0 and m["frame_id"] == "ned" and m["vehicle"] == v
            body = poses[round(m["timestamp"]["sec"] * 1e9 + m["timestamp"]["nsec"])]["pose"]["orientation"]
            heading = _heading_deg(body) + m["yaw_deg"]
            assert math.cos(math.radians(m["heading_deg"] - heading)) == pytest.approx(1.0, abs=1e-9)
            n, e, d = _optical_axis(m["orientation"])  # the camera looks along its pitch and heading
            assert d == pytest.approx(-math.sin(math.radians(m["pitch_deg"])), abs=1e-6)
            if m["pitch_deg"] > -89.0:
                assert math.degrees(math.atan2(e, n)) == pytest.approx(m["heading_deg"], abs=1e-3)
        by_t = {m["t_s"]: m for m in gimbal}
        assert (by_t[3.5]["pitch_deg"], by_t[3.5]["yaw_deg"]) == (-45.0, 30.0)  # reached after 0.5 s
        assert (by_t[5.1]["pitch_deg"], by_t[5.1]["yaw_deg"]) == (-54.0, 21.0)  # the second command, 0.1 s on
        assert (by_t[6.0]["pitch_deg"], by_t[6.0]["yaw_deg"]) == (-90.0, -60.0)
        # the 3D view: the camera's transform at every sample, the same attitude; its frustum from the first
        view = rrd[f"/world/gimbal/{v}"]
        assert view["sim_time"] == pytest.approx(t)
        quats = [row[0] for row in view["Transform3D:quaternion"]]
        for k in (0, 50, 100, 199):
            q = gimbal[k]["orientation"]
            assert quats[k] == pytest.approx([q["x"], q["y"], q["z"], q["w"]], abs=1e-6)
        assert rrd[f"/world/gimbal/{v}/camera"]["sim_time"] == [pytest.approx(3.02)]
    # one worker (every vehicle in the root process): the same gimbal messages, bit for bit
    _run(tmp_path / "w1", workers=1)
    one = read_topics(tmp_path / "w1" / "world.mcap")
    for v in (0, 1):
        assert _strip(one[f"/vehicle/{v}/gimbal"]) == _strip(mcap[f"/vehicle/{v}/gimbal"])
    assert "/vehicle/2/gimbal" not in one


def _strip(messages: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The messages without their wall-clock stamp (the run's epoch)."""
    return [{k: v for k, v in m.items() if k != "timestamp"} for m in messages]
