"""The estimator on synthetic sensor data: attitude, gyro bias, heading with declination, GPS/baro fusion."""

from __future__ import annotations

import math

import numpy as np

from harness.autopilot.estimator import Estimator
from harness.autopilot.mathutil import G_M_S2, quat_to_euler, rotate_inv, wrap_pi
from harness.autopilot.params import Params
from harness.core.geo import GeoRef, quat_from_euler
from harness.fdm.frame import Baro, Gps, Imu, Mag, SensorFrame, Truth

REF = GeoRef(47.0, 8.0, 500.0)
DECL = math.radians(3.0)
FIELD = (0.21 * math.cos(DECL), 0.21 * math.sin(DECL), 0.43)


def _frames(
    rng: np.random.Generator, euler: tuple[float, float, float], seconds: float, pos: tuple[float, float, float]
) -> list[SensorFrame]:
    q = quat_from_euler(*euler)
    spec = rotate_inv(q, (0.0, 0.0, -G_M_S2))
    mag = rotate_inv(q, FIELD)
    bias = (0.02, -0.015, 0.01)
    lat, lon, alt = REF.to_geo(*pos)
    truth = Truth(pos, (0.0, 0.0, 0.0), q, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), lat, lon, alt, True, False)
    out = []
    for k in range(round(seconds * 250)):
        t = (k + 1) * 4_000_000
        n = rng.normal(0.0, 1.0, 12)
        imu = Imu(
            (spec[0] + 0.05 * n[0], spec[1] + 0.05 * n[1], spec[2] + 0.05 * n[2]),
            (bias[0] + 0.003 * n[3], bias[1] + 0.003 * n[4], bias[2] + 0.003 * n[5]),
        )
        m = Mag((mag[0] + 0.002 * n[6], mag[1] + 0.002 * n[7], mag[2] + 0.002 * n[8])) if k % 5 == 0 else None
        b = Baro(95000.0, 20.0, alt + 0.1 * n[9] + 1.5) if k % 5 == 1 else None  # baro reads 1.5 m high
        g = None
        if k % 25 == 2:
            glat, glon, galt = REF.to_geo(pos[0] + 0.2 * n[10], pos[1] + 0.2 * n[11], pos[2])
            g = Gps(glat, glon, galt, (0.0, 0.0, 0.0), 3, 0.8, 1.2, 12, t)
        out.append(SensorFrame(t, 0, imu, truth, m, b, g))
    return out


def test_attitude_heading_and_gyro_bias_converge() -> None:
    params = Params(overrides={"EKF2_MAG_DECL": math.degrees(DECL)})
    est = Estimator(params)
    euler = (0.1, -0.05, 1.0)
    for f in _frames(np.random.default_rng(3), euler, 60.0, (5.0, -3.0, -2.0)):
        est.update(f, 0.004)
    r, p, y = quat_to_euler(est.q)
    assert abs(r - euler[0]) < math.radians(1.0)
    assert abs(p - euler[1]) < math.radians(1.0)
    assert abs(wrap_pi(y - euler[2])) < math.radians(2.0)
    assert abs(est.bias[0] - 0.02) < 0.005 and abs(est.bias[1] + 0.015) < 0.005 and abs(est.bias[2] - 0.01) < 0.005


def test_position_from_gps_and_baro_and_ground_truth_switch() -> None:
    params = Params()
    est = Estimator(params)
    frames = _frames(np.random.default_rng(4), (0.0, 0.0, 0.3), 20.0, (5.0, -3.0, -2.0))
    for f in frames:
        est.update(f, 0.004)
    assert est.pos_valid and est.ref is not None
    # the local origin is the first fix: the vehicle has not moved, so it sits near the origin
    assert math.hypot(est.pn, est.pe) < 0.3 and abs(est.pd) < 0.3 and math.hypot(est.vn, est.ve) < 0.1
    lat, lon, alt = est.geo()
    tlat, tlon, talt = REF.to_geo(5.0, -3.0, -2.0)
    assert abs(lat - tlat) * 111e3 < 0.3 and abs(lon - tlon) * 75e3 < 0.3
    assert abs(alt - talt) < 1.0  # the baro offset is taken out by the GPS altitude
    gt = Estimator(params, use_ground_truth=True)
    gt.update(frames[-1], 0.004)
    assert gt.q == frames[-1].truth.quat and gt.pos_valid
