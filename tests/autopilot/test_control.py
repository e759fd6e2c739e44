"""The control cascade's pure parts: mixer, attitude control, rate control, thrust-to-attitude, position control,
and the inner loop's one compiled call against its stages."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from harness.autopilot.control import PositionControl, TrajectorySetpoint, thrust_to_attitude
from harness.autopilot.inner import QUAD_X, AttitudeControl, RateControl, inner_loop, mix_quad_x, thrust_model
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


_unit = st.floats(-1.0, 1.0)
_rate = st.floats(-3.0, 3.0)


@given(
    st.tuples(_unit, _unit, _unit, _unit).filter(lambda q: sum(x * x for x in q) > 0.1),
    st.tuples(st.floats(-0.6, 0.6), st.floats(-0.6, 0.6), st.floats(-3.1, 3.1)),
    st.tuples(_rate, _rate, _rate),
    st.floats(0.0, 1.0),
    st.sampled_from([0.0, 0.4, 1.0]),
)
def test_inner_loop_is_the_stages_in_one_call(
    q: tuple[float, float, float, float],
    euler_sp: tuple[float, float, float],
    rates: tuple[float, float, float],
    thrust: float,
    fac: float,
) -> None:
    n = math.sqrt(sum(x * x for x in q))
    q = (q[0] / n, q[1] / n, q[2] / n, q[3] / n)
    qd = quat_from_euler(*euler_sp)
    params = Params()
    att, fused, staged = AttitudeControl(params), RateControl(params), RateControl(params)
    sat_pos = sat_neg = (False, False, False)
    for _ in range(3):  # integrators, previous rates and saturation flags carried from tick to tick
        motors = inner_loop(
            att.gains, fused.gains, fused.state, True, *q, *qd, 0.2, False, 0.0, 0.0, 0.0, *rates, thrust, 0.004,
            True, 0.05, fac,
        )  # fmt: skip
        torque = staged.update(att.update(q, qd, 0.2), rates, 0.004, sat_pos, sat_neg)
        mixed, sat_pos, sat_neg = mix_quad_x(*torque, thrust, 0.05)
        assert motors == tuple(thrust_model(m, fac) for m in mixed)  # the same bits
        assert list(fused.state) == [*staged.state[:6], *sat_pos, *sat_neg]


def test_rate_integrator_stops_growing_into_saturation() -> None:
    rate = RateControl(Params())
    free = RateControl(Params())
    for _ in range(50):  # a roll rate error the mixer cannot follow: saturated positive in roll
        rate.update((5.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.004, (True, False, False), (False, False, False))
        free.update((5.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.004)
    assert rate.i[0] == 0.0 and free.i[0] > 0.0
    # the other way it still integrates (it unwinds)
    rate.update((-5.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.004, (True, False, False), (False, False, False))
    assert rate.i[0] < 0.0


def test_thrust_model() -> None:
    # THR_MDL_FAC 1: thrust ~ u², the command is the square root; 0: linear; between them, between
    assert thrust_model(0.25, 1.0) == 0.5 and thrust_model(0.25, 0.0) == 0.25
    assert 0.25 < thrust_model(0.25, 0.5) < 0.5
