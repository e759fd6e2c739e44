"""Sensors: noise and bias match the configuration over 10,000 samples; GPS rate and latency."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from harness.fdm.physics import Physics, PhysicsConfig
from harness.fdm.sensors import SensorConfig, isa_altitude_m, isa_pressure_pa

N = 10_000


def at_rest_samples(cfg: SensorConfig, hover: bool = True) -> tuple[Physics, list[object]]:
    ph = Physics(PhysicsConfig(sensors=cfg, drag=False, spawn_ned_m=((0.0, 0.0, -50.0),)))
    u = ph.cfg.quad.hover_command
    frames = []
    for _ in range(250):
        ph.step([(u,) * 4])
    for _ in range(N):
        frames.append(ph.step([(u,) * 4])[0])
    return ph, frames


def test_imu_noise_and_bias_match_the_configuration() -> None:
    cfg = SensorConfig(
        accel_noise_m_s2=0.08,
        accel_bias_m_s2=(0.1, -0.2, 0.05),
        accel_bias_walk_m_s2_sqrt_s=0.0,
        gyro_noise_rad_s=0.01,
        gyro_bias_rad_s=(0.01, -0.02, 0.005),
        gyro_bias_walk_rad_s_sqrt_s=0.0,
    )
    _, frames = at_rest_samples(cfg)
    acc = np.array([f.imu.accel_body_m_s2 for f in frames])  # type: ignore[attr-defined]
    true_acc = np.array([(0.0, 0.0, -f.truth.accel_ned_m_s2[2] + 9.80665) for f in frames])  # type: ignore[attr-defined]
    gyro = np.array([f.imu.gyro_body_rad_s for f in frames]) - np.array([f.truth.rates_body_rad_s for f in frames])  # type: ignore[attr-defined]
    err = acc - np.array([[0.0, 0.0, -9.80665]]) - (true_acc - np.array([[0.0, 0.0, 9.80665]]))
    # standard error of a mean of N samples is sigma/sqrt(N): allow 5 of them; std within 5 %
    for i in range(3):
        assert err[:, i].mean() == pytest.approx(cfg.accel_bias_m_s2[i], abs=5 * 0.08 / math.sqrt(N))
        assert err[:, i].std() == pytest.approx(0.08, rel=0.05)
        assert gyro[:, i].mean() == pytest.approx(cfg.gyro_bias_rad_s[i], abs=5 * 0.01 / math.sqrt(N))
        assert gyro[:, i].std() == pytest.approx(0.01, rel=0.05)


def test_noise_off_gives_ideal_sensors() -> None:
    _, frames = at_rest_samples(SensorConfig(noise=False))
    f = frames[-1]
    assert f.imu.gyro_body_rad_s == f.truth.rates_body_rad_s  # type: ignore[attr-defined]


def test_baro_and_mag_rates_and_statistics() -> None:
    cfg = SensorConfig(baro_noise_m=0.2, baro_bias_m=0.5, baro_drift_m_sqrt_s=0.0, mag_noise_gauss=0.004)
    ph, frames = at_rest_samples(cfg)
    baro = [(f.t_ns, f.baro, f.truth.alt_amsl_m) for f in frames if f.baro is not None]  # type: ignore[attr-defined]
    mags = [f.mag for f in frames if f.mag is not None]  # type: ignore[attr-defined]
    assert len(baro) == pytest.approx(N / 5, abs=1) and len(mags) == pytest.approx(N / 5, abs=1)  # 50 Hz of 250 Hz
    alt_err = np.array([b.alt_amsl_m - truth for _, b, truth in baro])
    assert alt_err.mean() == pytest.approx(0.5, abs=5 * 0.2 / math.sqrt(len(alt_err)))
    assert alt_err.std() == pytest.approx(0.2, rel=0.07)
    assert isa_altitude_m(isa_pressure_pa(488.0)) == pytest.approx(488.0, abs=1e-6)
    field = ph.cfg.origin.magnetic_field_ned_gauss()
    mx = np.array([m.field_body_gauss[0] for m in mags])
    assert mx.mean() == pytest.approx(field[0] + cfg.mag_bias_gauss[0], abs=5 * 0.004 / math.sqrt(len(mx)))
    assert mx.std() == pytest.approx(0.004, rel=0.07)


def test_gps_arrives_at_its_rate_with_its_latency() -> None:
    cfg = SensorConfig(gps_rate_hz=5.0, gps_latency_s=0.2, noise=False)
    ph = Physics(PhysicsConfig(sensors=cfg, drag=False, spawn_ned_m=((0.0, 0.0, -30.0),)))
    # fall freely: the position changes every tick, so the delayed sample is recognisable
    frames = [ph.step([(0.0,) * 4])[0] for _ in range(500)]
    truth_at = {f.t_ns: f.truth for f in frames}
    gps = [(f.t_ns, f.gps) for f in frames if f.gps is not None]
    times = [t for t, _ in gps]
    assert all(b - a == 200_000_000 for a, b in itertools.pairwise(times)), "5 Hz exactly"
    for t, g in gps[1:]:
        assert g.measured_at_ns == t - 200_000_000
        past = truth_at[g.measured_at_ns]
        assert g.alt_amsl_m == pytest.approx(past.alt_amsl_m, abs=1e-9)  # the value of 0.2 s ago
        assert g.fix_type == 3
