"""Sensor models: IMU, magnetometer, barometer and GPS with rates, noise, bias, drift and latency.

Pure per-vehicle state fed with ground truth every tick; all randomness from the vehicle's own seeded
``numpy.random.Generator``, drawn in a fixed order, so the same seed gives bit-identical streams. The IMU,
sampled every tick, is one call of the numba-compiled ``imu.imu_sample``, imported when a ``SensorModel`` is
made; the slower sensors are plain float math. ``SensorConfig`` and the GPS profiles are defined in
``harness.fdm.config`` (this module is compiled by mypyc, which does not keep a dataclass's field types for
msgspec) and re-exported here.
"""

from __future__ import annotations

import collections
import math
from typing import Any

import numpy as np

from harness.core import jit
from harness.core.geo import EARTH_RADIUS_M, Quat, Vec3
from harness.fdm.config import GPS_PROFILES, GpsProfile, SensorConfig, gps_profile_names
from harness.fdm.frame import Baro, Gps, Imu, Mag

__all__ = [
    "GPS_PROFILES",
    "GpsProfile",
    "SensorConfig",
    "SensorModel",
    "gps_profile_names",
    "isa_altitude_m",
    "isa_pressure_pa",
]


def isa_pressure_pa(alt_amsl_m: float) -> float:
    return 101325.0 * (1.0 - 2.25577e-5 * alt_amsl_m) ** 5.25588


def isa_altitude_m(pressure_pa: float) -> float:
    return (1.0 - (pressure_pa / 101325.0) ** (1.0 / 5.25588)) / 2.25577e-5


def rotate_ned_to_body(q: Quat, v: Vec3) -> Vec3:
    """v_body = R(q)ᵀ v_ned for q rotating body to NED."""
    w, x, y, z = q
    vx, vy, vz = v
    # R^T v, expanded
    r00 = 1 - 2 * (y * y + z * z)
    r01 = 2 * (x * y - w * z)
    r02 = 2 * (x * z + w * y)
    r10 = 2 * (x * y + w * z)
    r11 = 1 - 2 * (x * x + z * z)
    r12 = 2 * (y * z - w * x)
    r20 = 2 * (x * z - w * y)
    r21 = 2 * (y * z + w * x)
    r22 = 1 - 2 * (x * x + y * y)
    return (r00 * vx + r10 * vy + r20 * vz, r01 * vx + r11 * vy + r21 * vz, r02 * vx + r12 * vy + r22 * vz)


class SensorModel:
    """The sensors of one vehicle. Call :meth:`sample` once per tick with the truth of that tick."""

    def __init__(self, cfg: SensorConfig, rng: np.random.Generator, tick_ns: int, mag_ned_gauss: Vec3) -> None:
        self.cfg = cfg
        self.rng = rng
        self.tick_ns = tick_ns
        self.mag_ned = mag_ned_gauss
        self._noise: list[float] = []
        self._noise_k: Any = []
        """The current block of standard normal draws as ``imu_sample`` takes it (``_noise`` as a list)."""
        self._noise_at = 0
        on = 1.0 if cfg.noise else 0.0
        self._on = on
        self._s = jit.floats([*(on * b for b in cfg.accel_bias_m_s2), *(on * b for b in cfg.gyro_bias_rad_s), 0.0])
        """The drifting biases, mutated by ``imu_sample``: accelerometer (3), gyro (3), barometer."""
        self._s[6] = on * cfg.baro_bias_m
        self._gps_err = [0.0, 0.0, 0.0]
        self._history: collections.deque[tuple[int, float, float, float, Vec3]] = collections.deque()
        """(t_ns, lat_deg, lon_deg, alt_amsl_m, vel_ned_m_s) of the last ticks, as long as the GPS latency."""
        self._next_mag = 0
        self._next_baro = 0
        self._next_gps = round(cfg.gps_latency_s * 1e9)
        self._mag_period = round(1e9 / cfg.mag_rate_hz)
        self._baro_period = round(1e9 / cfg.baro_rate_hz)
        self._gps_period = round(1e9 / cfg.gps_rate_hz)
        self._latency_ns = round(cfg.gps_latency_s * 1e9)
        dt = tick_ns * 1e-9
        self._walk_accel = cfg.accel_bias_walk_m_s2_sqrt_s * math.sqrt(dt) * on
        self._walk_gyro = cfg.gyro_bias_walk_rad_s_sqrt_s * math.sqrt(dt) * on
        self._walk_baro = cfg.baro_drift_m_sqrt_s * math.sqrt(dt) * on
        gps_dt = self._gps_period * 1e-9
        self._gps_a = math.exp(-gps_dt / cfg.gps_error_tau_s)
        self._gps_b = math.sqrt(1.0 - self._gps_a**2) * on
        # per-tick constants (the same products the formulas below would form every tick)
        self._an, self._gn = cfg.accel_noise_m_s2 * on, cfg.gyro_noise_rad_s * on
        self._imu_c = jit.floats([self._walk_accel, self._walk_gyro, self._an, self._gn, self._walk_baro])
        from harness.fdm.imu import imu_sample_entry  # numba only where sensors are stepped

        self._imu_sample = imu_sample_entry
        self._mn = cfg.mag_noise_gauss * on
        self._mb = (on * cfg.mag_bias_gauss[0], on * cfg.mag_bias_gauss[1], on * cfg.mag_bias_gauss[2])
        self._bn = cfg.baro_noise_m * on
        self._vn = cfg.gps_vel_noise_m_s * on
        self._eph = max(0.5, cfg.gps_noise_m * 2.0)
        self._epv = max(0.8, cfg.gps_alt_noise_m * 2.0)

    @property
    def accel_bias(self) -> Vec3:
        """The accelerometer's bias now (turn-on bias plus random walk), m/s²."""
        s = self._s
        return (float(s[0]), float(s[1]), float(s[2]))

    @property
    def gyro_bias(self) -> Vec3:
        """The gyro's bias now, rad/s."""
        s = self._s
        return (float(s[3]), float(s[4]), float(s[5]))

    @property
    def baro_bias_m(self) -> float:
        """The barometer's bias now (turn-on bias plus drift), m."""
        return float(self._s[6])

    def _normals(self, n: int) -> list[float]:
        """The next ``n`` standard normal draws of this vehicle's stream. Drawn from the generator in blocks
        (one numpy call per 4096 values instead of several per tick): same seed, same sequence."""
        at = self._noise_at
        if at + n > len(self._noise):
            block = self.rng.standard_normal(4096)
            self._noise = block.tolist()
            self._noise_k = block if jit.ENABLED else self._noise
            at = 0
        self._noise_at = at + n
        return self._noise[at : at + n]

    def sample(
        self,
        t_ns: int,
        q: Quat,
        specific_force_body_m_s2: Vec3,
        rates_body_rad_s: Vec3,
        lat_deg: float,
        lon_deg: float,
        alt_amsl_m: float,
        vel_ned_m_s: Vec3,
    ) -> tuple[Imu, Mag | None, Baro | None, Gps | None]:
        # the draws of a tick, in this order: 12 (IMU), 1 (baro drift), then 3 (mag), 1 (baro), 6 (GPS) when
        # those sample; a fixed number per sensor keeps the streams aligned
        at = self._noise_at
        if at + 13 > len(self._noise):
            z, at = jit.floats([*self._normals(12), *self._normals(1)]), 0
        else:
            z = self._noise_k
            self._noise_at = at + 13
        a0, a1, a2, g0, g1, g2 = self._imu_sample(
            z, at, self._s, self._imu_c, *specific_force_body_m_s2, *rates_body_rad_s
        )
        imu = Imu((a0, a1, a2), (g0, g1, g2))
        mag = baro = gps = None
        if t_ns >= self._next_mag:
            self._next_mag += self._mag_period
            m = rotate_ned_to_body(q, self.mag_ned)
            mz = self._normals(3)
            mn, mb = self._mn, self._mb
            mag = Mag((m[0] + mb[0] + mn * mz[0], m[1] + mb[1] + mn * mz[1], m[2] + mb[2] + mn * mz[2]))
        if t_ns >= self._next_baro:
            self._next_baro += self._baro_period
            measured_alt = alt_amsl_m + self.baro_bias_m + self._bn * self._normals(1)[0]
            pressure = isa_pressure_pa(measured_alt)
            baro = Baro(pressure, 15.0 - 0.0065 * alt_amsl_m, isa_altitude_m(pressure))
        history = self._history
        history.append((t_ns, lat_deg, lon_deg, alt_amsl_m, vel_ned_m_s))
        oldest = t_ns - self._latency_ns
        while len(history) > 1 and history[1][0] <= oldest:
            history.popleft()
        if t_ns >= self._next_gps:
            self._next_gps += self._gps_period
            old_t, old_lat, old_lon, old_alt, old_vel = history[0]
            gz = self._normals(6)
            e = self._gps_err
            for i in range(3):
                e[i] = self._gps_a * e[i] + self._gps_b * gz[i]
            cfg = self.cfg
            rm = EARTH_RADIUS_M
            vn = self._vn
            gps = Gps(
                old_lat + math.degrees(e[0] * cfg.gps_noise_m / rm),
                old_lon + math.degrees(e[1] * cfg.gps_noise_m / (rm * math.cos(math.radians(old_lat)))),
                old_alt + e[2] * cfg.gps_alt_noise_m,
                (old_vel[0] + vn * gz[3], old_vel[1] + vn * gz[4], old_vel[2] + vn * gz[5]),
                cfg.gps_fix_type,
                self._eph,
                self._epv,
                cfg.gps_satellites,
                old_t,
            )
        return imu, mag, baro, gps
