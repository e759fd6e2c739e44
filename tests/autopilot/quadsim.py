"""A small rigid-body quad-X model producing ``SensorFrame``s, for fast unit-level closed-loop tests of the
autopilot (sign conventions, mode logic) independent of the JSBSim FDM. Acceptance tests use the real FDM.
"""

from __future__ import annotations

import math

import numpy as np

from harness.autopilot.mathutil import quat_mul, quat_normalize, rotate, rotate_inv
from harness.core.geo import GeoRef
from harness.fdm.frame import Baro, Gps, Imu, Mag, SensorFrame, Truth

G = 9.80665
_DECL = math.radians(3.0)  # as the FDM's world at the default origin
_GEOM = ((0.707, 0.707, 1.0), (-0.707, -0.707, 1.0), (0.707, -0.707, -1.0), (-0.707, 0.707, -1.0))


class QuadSim:
    """x forward, y right positions of the motors times the arm; yaw sign +1 for CCW motors."""

    def __init__(self, rng: np.random.Generator, noise: bool = True, gps_fix: int = 3, tick_hz: int = 250) -> None:
        self.rng = rng
        self.noise = noise
        self.gps_fix = gps_fix
        self.mass = 1.5
        self.arm = 0.25
        self.t_max = self.mass * G / (4 * 0.52)  # thrust = t_max * u^2 (like the FDM): hover at u = 0.72
        self.inertia = (0.03, 0.03, 0.05)
        self.k_yaw = 0.016
        self.tick_ns = 1_000_000_000 // tick_hz
        self.sub = 4
        self.t_ns = 0
        self.pos = [0.0, 0.0, 0.0]
        self.vel = [0.0, 0.0, 0.0]
        self.q = (1.0, 0.0, 0.0, 0.0)
        self.w = [0.0, 0.0, 0.0]
        self.u = [0.0, 0.0, 0.0, 0.0]
        self.acc = (0.0, 0.0, 0.0)
        self.ref = GeoRef(47.397742, 8.545594, 488.0)
        self.wind = (0.0, 0.0, 0.0)
        self._n = 0
        self.on_ground = True

    def step(self, motors: tuple[float, ...]) -> SensorFrame:
        dt = self.tick_ns / self.sub * 1e-9
        for _ in range(self.sub):
            for i in range(4):
                self.u[i] += (min(max(motors[i], 0.0), 1.0) - self.u[i]) * min(dt / 0.02, 1.0)
            th = [self.t_max * u * u for u in self.u]
            total = sum(th)
            tx = sum(-_GEOM[i][1] * th[i] for i in range(4)) * self.arm
            ty = sum(_GEOM[i][0] * th[i] for i in range(4)) * self.arm
            tz = sum(_GEOM[i][2] * th[i] for i in range(4)) * self.k_yaw
            fb = (0.0, 0.0, -total)
            fw = rotate(self.q, fb)
            rvx, rvy, rvz = (self.vel[0] - self.wind[0], self.vel[1] - self.wind[1], self.vel[2] - self.wind[2])
            drag = 0.25
            ax = fw[0] / self.mass - drag * rvx
            ay = fw[1] / self.mass - drag * rvy
            az = fw[2] / self.mass + G - drag * rvz
            if self.pos[2] >= 0.0 and az >= 0.0:
                ax = ay = az = 0.0
                self.vel = [0.0, 0.0, 0.0]
                self.w = [0.0, 0.0, 0.0]
                self.pos[2] = 0.0
                self.on_ground = True
            else:
                self.on_ground = False
            self.acc = (ax, ay, az)
            for k, a in enumerate((ax, ay, az)):
                self.vel[k] += a * dt
                self.pos[k] += self.vel[k] * dt
            if self.pos[2] > 0.0:
                self.pos[2] = 0.0
            ix, iy, iz = self.inertia
            p, q, r = self.w
            self.w[0] += (tx - (iz - iy) * q * r) / ix * dt
            self.w[1] += (ty - (ix - iz) * p * r) / iy * dt
            self.w[2] += (tz - (iy - ix) * p * q) / iz * dt
            if self.on_ground:
                self.w = [0.0, 0.0, 0.0]
            p, q, r = self.w
            h = 0.5 * dt
            self.q = quat_normalize(quat_mul(self.q, (1.0, p * h, q * h, r * h)))
        self.t_ns += self.tick_ns
        self._n += 1
        return self.frame()

    def _nz(self, s: float) -> float:
        return float(self.rng.normal(0.0, s)) if self.noise else 0.0

    def frame(self) -> SensorFrame:
        spec = rotate_inv(self.q, (self.acc[0], self.acc[1], self.acc[2] - G))
        imu = Imu(
            (spec[0] + self._nz(0.05), spec[1] + self._nz(0.05), spec[2] + self._nz(0.05)),
            (self.w[0] + self._nz(0.005), self.w[1] + self._nz(0.005), self.w[2] + self._nz(0.005)),
        )
        lat, lon, alt = self.ref.to_geo(*self.pos)
        truth = Truth(
            tuple(self.pos),  # type: ignore[arg-type]
            tuple(self.vel),  # type: ignore[arg-type]
            self.q,
            tuple(self.w),  # type: ignore[arg-type]
            self.acc,
            lat,
            lon,
            alt,
            self.on_ground,
            False,
        )
        mag = baro = gps = None
        if self._n % 5 == 0:
            mb = rotate_inv(self.q, (0.21 * math.cos(_DECL), 0.21 * math.sin(_DECL), 0.43))
            mag = Mag((mb[0] + self._nz(0.002), mb[1] + self._nz(0.002), mb[2] + self._nz(0.002)))
        if self._n % 5 == 1:
            baro = Baro(95000.0, 20.0, alt + self._nz(0.1))
        if self._n % 25 == 2 and self.gps_fix > 0:
            glat, glon, galt = self.ref.to_geo(self.pos[0] + self._nz(0.1), self.pos[1] + self._nz(0.1), self.pos[2])
            gps = Gps(
                glat,
                glon,
                galt + self._nz(0.3),
                (self.vel[0] + self._nz(0.05), self.vel[1] + self._nz(0.05), self.vel[2] + self._nz(0.05)),
                self.gps_fix,
                0.8,
                1.2,
                12 if self.gps_fix >= 3 else 3,
                self.t_ns,
            )
        return SensorFrame(self.t_ns, 0, imu, truth, mag, baro, gps)


def fly(ap: object, sim: QuadSim, seconds: float, clock: object | None = None) -> list[tuple[int, tuple]]:
    """Run the closed loop; returns [(t_ns, truth pos)] at every tick. ``clock`` (ManualClock) follows sim time."""
    from harness.autopilot.autopilot import Autopilot

    assert isinstance(ap, Autopilot)
    out = []
    frame = sim.frame()
    for _ in range(round(seconds * 1e9 / sim.tick_ns)):
        if clock is not None:
            clock.advance_to(frame.t_ns)  # type: ignore[attr-defined]
        motors = ap.step(frame)
        frame = sim.step(motors)
        out.append((frame.t_ns, tuple(sim.pos)))
    return out
