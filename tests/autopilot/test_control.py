"""The control cascade's pure parts: mixer, attitude control, thrust-to-attitude, position control."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from harness.autopilot.control import PositionControl, TrajectorySetpoint, thrust_to_attitude
from harness.autopilot.inner import QUAD_X, AttitudeControl, mix_quad_x
from harness.autopilot.mathutil import quat_to_euler
from harness.autopilot.params import Params
from harness.core.geo import quat_from_euler


def _torques(m: tuple[float, ...]) -> tuple[float, float, float, float]:
    r = sum(QUAD_X[i][0] * m[i] for i in range(4))
    p = sum(QUAD_X[i][1] * m[i] for i in range(4))
    y = sum(QUAD_X[i][2] * m[i] for i in range(4))
    return r, p, y, sum(m) / 4


def test_mixer_unsaturated_is_exact() -> None:
    m, sp, sn = mix_quad_x(0.05, -0.03, 0.02, 0.5)
    r, p, y, t = _torques(m)
    assert math.isclose(r, 4 * 0.707107**2 * 0.05, rel_tol=1e-4)
    assert math.isclose(p, -4 * 0.707107**2 * 0.03, rel_tol=1e-4)
    assert math.isclose(y, 0.08, rel_tol=1e-6) and math.isclose(t, 0.5, rel_tol=1e-6)
    assert not any(sp) and not any(sn)
    # motor 0 is front right: a positive roll (right side down) needs less thrust on the right
    assert m[0] < m[2]


def test_mixer_yaw_gives_way_first() -> None:
    m, sp, _ = mix_quad_x(0.6, 0.0, 0.5, 0.5)
    r, _, y, _ = _torques(m)
    assert math.isclose(r, 4 * 0.707107**2 * 0.6, rel_tol=1e-3)  # roll kept in full
    assert y < 0.5 and sp[2]  # yaw cut and flagged


@given(st.floats(-2, 2), st.floats(-2, 2), st.floats(-2, 2), st.floats(0, 1), st.floats(0, 0.2))
def test_mixer_outputs_in_range_and_keep_sign(roll: float, pitch: float, yaw: float, thr: float, idle: float) -> None:
    m, _, _ = mix_quad_x(roll, pitch, yaw, thr, idle)
    assert all(idle - 1e-9 <= v <= 1.0 + 1e-9 for v in m)
    r, _, _, _ = _torques(m)
    if abs(roll) > 1e-6 and abs(pitch) < 1e-9:
        assert r * roll >= -1e-9


def test_attitude_control_turns_towards_setpoint() -> None:
    ctl = AttitudeControl(Params())
    level = (1.0, 0.0, 0.0, 0.0)
    rr, rp, ry = ctl.update(level, quat_from_euler(0.2, 0.0, 0.0))
    assert rr > 0 and abs(rp) < 1e-9 and abs(ry) < 1e-9
    rr, rp, ry = ctl.update(level, quat_from_euler(0.0, -0.1, 0.0))
    assert rp < 0 and abs(rr) < 1e-9
    rr, rp, ry = ctl.update(level, quat_from_euler(0.0, 0.0, 0.5))
    assert ry > 0 and abs(rr) < 1e-9
    # rates are limited
    rr, _, _ = ctl.update(level, quat_from_euler(3.0, 0.0, 0.0))
    assert rr <= math.radians(220.0) + 1e-9


def test_thrust_to_attitude() -> None:
    q, n = thrust_to_attitude((0.0, 0.0, -0.5), 1.0)
    r, p, y = quat_to_euler(q)
    assert abs(r) < 1e-9 and abs(p) < 1e-9 and math.isclose(y, 1.0) and math.isclose(n, 0.5)
    # thrust tilted north (accelerate north) with yaw 0 = nose down (negative pitch)
    q, _ = thrust_to_attitude((0.1, 0.0, -0.5), 0.0)
    r, p, _ = quat_to_euler(q)
    assert p < -0.1 and abs(r) < 1e-9
    # east with yaw 0 = roll right
    q, _ = thrust_to_attitude((0.0, 0.1, -0.5), 0.0)
    r, p, _ = quat_to_euler(q)
    assert r > 0.1


def test_position_control_pushes_towards_setpoint_within_tilt_limit() -> None:
    params = Params()
    ctl = PositionControl(params)
    sp = TrajectorySetpoint()
    sp.set((100.0, 0.0, -10.0))
    thr = ctl.update(sp, (0.0, 0.0, -10.0), (0.0, 0.0, 0.0), 0.01)
    assert thr[0] > 0 and abs(thr[1]) < 1e-9
    tilt = math.atan2(math.hypot(thr[0], thr[1]), -thr[2])
    assert tilt <= math.radians(params["MPC_TILTMAX_AIR"]) + 1e-6
    sp.set((0.0, 0.0, -20.0))
    ctl.reset()
    thr = ctl.update(sp, (0.0, 0.0, -10.0), (0.0, 0.0, 0.0), 0.01)
    assert -thr[2] > params["MPC_THR_HOVER"]
