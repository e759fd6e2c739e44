"""State estimation from the sensors: attitude complementary filter and position/velocity fusion.

Attitude: a Mahony-style complementary filter on the gyro, corrected towards gravity by the accelerometer
(with the linear acceleration measured by GPS velocity taken out) and in heading by the magnetometer
(``EKF2_MAG_DECL`` is the declination), with gyro bias learning.

Position / velocity: accelerometer (rotated to NED, gravity removed) predicts at every tick; GPS position
and velocity correct the horizontal axes against the state at the time the GPS sample was measured (a
short history covers GPS latency); the barometer corrects height; GPS altitude only sets the AMSL
offset of the local frame. The local NED frame has its origin where the first good GPS fix was taken
(like PX4's EKF origin) unless an origin is given.

``use_ground_truth`` replaces all of this by the frame's ``truth`` (debugging only).
It runs every tick for every vehicle: the per-tick part (attitude filter and prediction) is one call of the
numba-compiled ``predict`` (``harness.core.jit``) over floats and the filter's state array; the GPS and
barometer corrections (10 and 50 Hz) are plain float math.
"""

from __future__ import annotations

import math

from harness.autopilot.mathutil import G_M_S2
from harness.autopilot.params import Params
from harness.core.geo import GeoRef, quat_from_euler
from harness.core.jit import Floats, compiled, floats, kernel
from harness.fdm.frame import Gps, SensorFrame

_HIST = 64


GPS_CHECK_NS = 10_000_000_000
"""PX4 EKF2 uses the GPS (and reports a global position) once its checks have passed for 10 s."""


@kernel
def predict(
    s: Floats,
    g: Floats,
    att: bool,
    slow: bool,
    w: float,
    x: float,
    y: float,
    z: float,
    gx: float,
    gy: float,
    gz: float,
    fx: float,
    fy: float,
    fz: float,
    has_mag: bool,
    bx: float,
    by: float,
    bz: float,
    mag_recent: bool,
    pn: float,
    pe: float,
    pd: float,
    vn: float,
    ve: float,
    vd: float,
    abn: float,
    abe: float,
    abd: float,
    dt: float,
) -> tuple[float, float, float, float, float, float, float, float, float, float, float, float, float, float]:
    """One tick of the filter. If ``att``: the attitude (w, x, y, z) integrated from the gyro (f: accelerometer,
    b: magnetometer if ``has_mag``) with its corrections and bias learning (faster until ``slow``); then the
    position and velocity predicted from the accelerometer. ``s``: gyro bias (3), GPS linear acceleration (3),
    held heading error, mutated; ``g``: ATT_W_ACC, ATT_W_MAG, ATT_W_GYRO_BIAS, declination.
    Returns (attitude (4), body rates (3), position (3), velocity (3), vertical acceleration)."""
    p = q_ = r = 0.0
    if att:
        # the rotation body -> world R(q), each term formed once (the same products as written out in full)
        xx, yy, zz = x * x, y * y, z * z
        xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
        r00, r01, r02 = 1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)
        r10, r11, r12 = 2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)
        r20, r21, r22 = 2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)
        ex = ey = ez = 0.0
        # accelerometer: measured "up" (specific force) versus estimated up = R^T (g - a_lin) / |.|
        fn = math.sqrt(fx * fx + fy * fy + fz * fz)
        if 0.5 * G_M_S2 < fn < 1.5 * G_M_S2:
            rn, re, rd = s[3], s[4], s[5] - G_M_S2  # world specific force expected: a_lin - g
            rl = math.sqrt(rn * rn + re * re + rd * rd)
            rn, re, rd = rn / rl, re / rl, rd / rl
            # world -> body: R^T v
            vx = r00 * rn + r10 * re + r20 * rd
            vy = r01 * rn + r11 * re + r21 * rd
            vz = r02 * rn + r12 * re + r22 * rd
            mx, my, mz = fx / fn, fy / fn, fz / fn
            k = g[0] if slow else 10.0 * g[0]
            ex = k * (my * vz - mz * vy)
            ey = k * (mz * vx - mx * vz)
            ez = k * (mx * vy - my * vx)
        if has_mag:
            # field in world: R m; its heading error is held until the next sample (mag is slower than the tick)
            wn = r00 * bx + r01 * by + r02 * bz
            we = r10 * bx + r11 * by + r12 * bz
            if wn * wn + we * we > 1e-6:
                err = math.atan2(we, wn) - g[3]
                s[6] = (err + math.pi) % (2.0 * math.pi) - math.pi
        if mag_recent:
            # world-z correction -k*err, into body: R^T (0, 0, 1)
            c = -g[1] * s[6] * (1.0 if slow else 10.0)
            ex += c * r20
            ey += c * r21
            ez += c * r22
        kb = g[2] * dt
        b0 = s[0] = s[0] - kb * ex
        b1 = s[1] = s[1] - kb * ey
        b2 = s[2] = s[2] - kb * ez
        p, q_, r = gx - b0, gy - b1, gz - b2
        ox, oy, oz = p + ex, q_ + ey, r + ez
        h = 0.5 * dt
        nw = w + h * (-x * ox - y * oy - z * oz)
        nx = x + h * (w * ox + y * oz - z * oy)
        ny = y + h * (w * oy - x * oz + z * ox)
        nz = z + h * (w * oz + x * oy - y * ox)
        n = 1.0 / math.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
        w, x, y, z = nw * n, nx * n, ny * n, nz * n
    # position and velocity: the accelerometer rotated to NED, gravity removed
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    an = (1 - 2 * (yy + zz)) * fx + 2 * (xy - wz) * fy + 2 * (xz + wy) * fz + abn
    ae = 2 * (xy + wz) * fx + (1 - 2 * (xx + zz)) * fy + 2 * (yz - wx) * fz + abe
    ad = 2 * (xz - wy) * fx + 2 * (yz + wx) * fy + (1 - 2 * (xx + yy)) * fz + G_M_S2 + abd
    h = 0.5 * dt * dt
    pn += vn * dt + an * h
    pe += ve * dt + ae * h
    pd += vd * dt + ad * h
    return (w, x, y, z, p, q_, r, pn, pe, pd, vn + an * dt, ve + ae * dt, vd + ad * dt, ad)


_predict = compiled(predict)


class Estimator:
    def __init__(self, params: Params, use_ground_truth: bool = False, origin: GeoRef | None = None) -> None:
        self.params = params
        self.use_ground_truth = use_ground_truth
        self.ref: GeoRef | None = origin
        self._ref_given = origin is not None
        self.q = (1.0, 0.0, 0.0, 0.0)
        self._s = floats([0.0] * 7)
        """The filter's own state, mutated by ``predict``: gyro bias (3), linear acceleration from GPS (3),
        heading error held from the last magnetometer sample."""
        self.rates = (0.0, 0.0, 0.0)
        self.accel_body = (0.0, 0.0, -G_M_S2)
        self.pn = self.pe = self.pd = 0.0
        self.vn = self.ve = self.vd = 0.0
        self.abn = self.abe = self.abd = 0.0
        self.att_valid = False
        self.pos_valid = False
        self.gps_good_since_ns: int | None = None
        """Since when every GPS sample passed the checks (None: the last one failed)."""
        self.height_valid = False
        self.ref_alt_valid = False
        self.last_gps_ns = -(10**18)
        self.last_baro_ns = -(10**18)
        self.last_mag_ns = -(10**18)
        self.last_imu_ns = -(10**18)
        self.gps: Gps | None = None
        self._baro_ref: float | None = None
        self._baro_n = 0
        self._ref_alt_sum = 0.0
        self._ref_alt_n = 0
        self._hist: list[tuple[int, float, float, float, float, float, float]] = []
        self._hist_i = 0
        self._alin_tau = 1.0
        """Low-pass time constant of the GPS-measured linear acceleration (GPS velocity noise, differentiated)."""
        self._gps_vel_prev: tuple[int, float, float, float] | None = None
        self._truth0: tuple[float, float, float] | None = None
        self._t_ns = 0
        self._fast_until_ns = 0
        self._settled = False
        """Until then the attitude corrections run 10x faster (convergence after initialisation)."""
        self.acc_d = 0.0
        """Estimated vertical (down) acceleration, m/s²."""
        self._g = floats([0.0] * 4)
        """ATT_W_ACC, ATT_W_MAG, ATT_W_GYRO_BIAS, the magnetic declination (rad)."""
        self._ver = -1
        self._load()

    def _load(self) -> None:
        p = self.params
        self._ver = p.version
        self._decl = math.radians(p["EKF2_MAG_DECL"])
        self._g[:] = (p["ATT_W_ACC"], p["ATT_W_MAG"], p["ATT_W_GYRO_BIAS"], self._decl)
        self._tau_gps_p = 2.0 * p["EKF2_GPS_P_NOISE"]
        self._tau_gps_v = 1.0 * p["EKF2_GPS_V_NOISE"]
        self._tau_baro = 2.0 * p["EKF2_BARO_NOISE"]
        self._req_sats = int(p["EKF2_REQ_NSATS"])
        self._req_eph = p["EKF2_REQ_EPH"]

    # ---- properties the rest of the autopilot reads ----
    @property
    def bias(self) -> tuple[float, float, float]:
        """Gyro bias estimate, rad/s."""
        s = self._s
        return (float(s[0]), float(s[1]), float(s[2]))

    @property
    def alt_amsl_m(self) -> float:
        return (self.ref.alt_m if self.ref is not None else 0.0) - self.pd

    def geo(self) -> tuple[float, float, float]:
        """Estimated (lat_deg, lon_deg, alt_amsl_m); zeros before a GPS reference exists."""
        if self.ref is None:
            return (0.0, 0.0, -self.pd)
        return self.ref.to_geo(self.pn, self.pe, self.pd)

    @property
    def yaw(self) -> float:
        w, x, y, z = self.q
        return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))

    def global_position_ok(self, t_ns: int) -> bool:
        """The global position is usable, as PX4's EKF2 reports it: GPS checks passed for ``GPS_CHECK_NS``
        (the altitude reference and the position filter have settled; PX4 sets home only then)."""
        since = self.gps_good_since_ns
        return self.pos_valid and self.gps_fix_ok() and since is not None and t_ns - since >= GPS_CHECK_NS

    def gps_fix_ok(self) -> bool:
        g = self.gps
        return (
            g is not None
            and g.fix_type >= 3
            and g.satellites >= self._req_sats
            and g.eph_m <= self._req_eph
            and self._t_ns - self.last_gps_ns < 1_000_000_000
        )

    # ---- the update ----
    def forget_gps_motion(self) -> None:
        """GPS gone: stop correcting the attitude for the linear acceleration its velocity last showed."""
        s = self._s
        s[3] = s[4] = s[5] = 0.0

    def update(self, frame: SensorFrame, dt: float) -> None:
        if self.params.version != self._ver:
            self._load()
        self._t_ns = frame.t_ns
        if self.use_ground_truth:
            self._update_truth(frame)
            return
        imu = frame.imu
        self.last_imu_ns = frame.t_ns
        fx, fy, fz = imu.accel_body_m_s2
        self.accel_body = imu.accel_body_m_s2
        att = self.att_valid
        if not att:
            fn = math.sqrt(fx * fx + fy * fy + fz * fz)
            if frame.mag is not None and 0.9 * G_M_S2 < fn < 1.1 * G_M_S2:
                self._init_attitude(fx, fy, fz, frame.mag.field_body_gauss)
                self._fast_until_ns = frame.t_ns + 2_000_000_000
            self.rates = imu.gyro_body_rad_s
        elif not self._settled and frame.t_ns > self._fast_until_ns:
            # what the accelerometer-bias states learned while the attitude converged is not bias (the
            # attitude step of this tick does not use them: they are cleared before it)
            self._settled = True
            self.abn = self.abe = self.abd = 0.0
        self._predict(frame, att, fx, fy, fz, dt)

    def _init_attitude(self, fx: float, fy: float, fz: float, mag: tuple[float, float, float]) -> None:
        roll = math.atan2(-fy, -fz)
        pitch = math.atan2(fx, math.sqrt(fy * fy + fz * fz))
        cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
        mx, my, mz = mag
        # de-rotate the field by roll and pitch to the horizontal plane
        hx = mx * cp + my * sr * sp + mz * cr * sp
        hy = my * cr - mz * sr
        yaw = math.atan2(-hy, hx) + self._decl
        self.q = quat_from_euler(roll, pitch, yaw)
        self.att_valid = True
        self.last_mag_ns = self._t_ns

    def _predict(self, frame: SensorFrame, att: bool, fx: float, fy: float, fz: float, dt: float) -> None:
        """The per-tick part in one compiled call (``predict``): the attitude filter if ``att``, then the
        position and velocity prediction; the history entry for the delayed GPS fusion."""
        t = frame.t_ns
        gx, gy, gz = frame.imu.gyro_body_rad_s
        mag = frame.mag
        if mag is not None and att:
            self.last_mag_ns = t
            bx, by, bz = mag.field_body_gauss
        else:
            bx = by = bz = 0.0
        w, x, y, z, p, q, r, self.pn, self.pe, self.pd, self.vn, self.ve, self.vd, self.acc_d = _predict(
            self._s, self._g, att, t > self._fast_until_ns, *self.q, gx, gy, gz, fx, fy, fz, mag is not None,
            bx, by, bz, t - self.last_mag_ns < 500_000_000, self.pn, self.pe, self.pd, self.vn, self.ve, self.vd,
            self.abn, self.abe, self.abd, dt,
        )  # fmt: skip
        if att:
            self.q = (w, x, y, z)
            self.rates = (p, q, r)
        entry = (t, self.pn, self.pe, self.pd, self.vn, self.ve, self.vd)
        hist = self._hist
        if len(hist) < _HIST:
            hist.append(entry)
        else:
            i = self._hist_i
            hist[i] = entry
            self._hist_i = (i + 1) % _HIST
        baro = frame.baro
        if baro is not None:
            self._fuse_baro(baro.alt_amsl_m, t)
        gps = frame.gps
        if gps is not None:
            self.gps = gps
            self._fuse_gps(gps, t)

    def _past(self, t_ns: int) -> tuple[int, float, float, float, float, float, float]:
        best = None
        for e in self._hist:
            if e[0] <= t_ns and (best is None or e[0] > best[0]):
                best = e
        if best is None:
            best = min(self._hist, key=lambda e: e[0])
        return best

    def _fuse_baro(self, alt_m: float, t_ns: int) -> None:
        self._baro_n += 1
        if self._baro_ref is None:
            self._baro_ref = alt_m + self.pd
            self.last_baro_ns = t_ns
            self.height_valid = True
            return
        if self._baro_n <= 50:
            # the local height origin: the average of the first samples, not one noisy sample
            self._baro_ref += (alt_m + self.pd - self._baro_ref) / self._baro_n
        dt = (t_ns - self.last_baro_ns) * 1e-9
        self.last_baro_ns = t_ns
        if dt <= 0.0:
            return
        innov = (self._baro_ref - alt_m) - self.pd
        k = 1.0 - math.exp(-dt / self._tau_baro)
        self.pd += k * innov
        self.vd += 0.6 * k * k / dt * innov
        self.abd += 0.05 * k * innov

    def _fuse_gps(self, g: Gps, t_ns: int) -> None:
        good = g.fix_type >= 3 and g.satellites >= self._req_sats and g.eph_m <= self._req_eph
        if not good:
            self.gps_good_since_ns = None
            return
        if self.gps_good_since_ns is None:
            self.gps_good_since_ns = t_ns
        if self.ref is None:
            self.ref = GeoRef(g.lat_deg, g.lon_deg, g.alt_amsl_m)
            self.pn = self.pe = 0.0
            self.vn, self.ve = g.vel_ned_m_s[0], g.vel_ned_m_s[1]
            self._hist.clear()
            self._hist_i = 0
        n, e, _ = self.ref.to_ned(g.lat_deg, g.lon_deg, g.alt_amsl_m)
        # AMSL offset of the local frame: average of GPS altitude + local down position
        self._ref_alt_n += 1
        sample = g.alt_amsl_m + self.pd
        if not self._ref_given:
            self._ref_alt_sum += sample
            m = self._ref_alt_sum / self._ref_alt_n if self._ref_alt_n < 200 else None
            if m is not None:
                self.ref.alt_m = m
            else:
                self.ref.alt_m += 0.005 * (sample - self.ref.alt_m)
        self.ref_alt_valid = True
        dt = (t_ns - self.last_gps_ns) * 1e-9 if self.pos_valid else 0.0
        self.last_gps_ns = t_ns
        vn_g, ve_g, vd_g = g.vel_ned_m_s
        prev = self._gps_vel_prev
        if prev is not None and 0.0 < (g.measured_at_ns - prev[0]) * 1e-9 < 1.0:
            gdt = (g.measured_at_ns - prev[0]) * 1e-9
            a = self._s  # the linear acceleration: a[3:6]
            k = 1.0 - math.exp(-gdt / self._alin_tau)
            a[3] += k * ((vn_g - prev[1]) / gdt - a[3])
            a[4] += k * ((ve_g - prev[2]) / gdt - a[4])
            a[5] += k * ((vd_g - prev[3]) / gdt - a[5])
        self._gps_vel_prev = (g.measured_at_ns, vn_g, ve_g, vd_g)
        if not self.pos_valid or dt <= 0.0 or dt > 2.0:
            self.pn, self.pe = n, e
            self.vn, self.ve = vn_g, ve_g
            self.pos_valid = True
            return
        past = self._past(g.measured_at_ns)
        ipn, ipe = n - past[1], e - past[2]
        ivn, ive, ivd = vn_g - past[4], ve_g - past[5], vd_g - past[6]
        kp = 1.0 - math.exp(-dt / self._tau_gps_p)
        kv = 1.0 - math.exp(-dt / self._tau_gps_v)
        self.pn += kp * ipn
        self.pe += kp * ipe
        self.vn += kv * ivn + 0.5 * kp * kp / dt * ipn
        self.ve += kv * ive + 0.5 * kp * kp / dt * ipe
        self.vd += 0.3 * kv * ivd
        kb = 0.1 * kv
        self.abn += kb * ivn
        self.abe += kb * ive

    def _update_truth(self, frame: SensorFrame) -> None:
        tr = frame.truth
        if self._truth0 is None:
            self._truth0 = tr.pos_ned_m
            if self.ref is None:
                self.ref = GeoRef(tr.lat_deg, tr.lon_deg, tr.alt_amsl_m)
        p0 = self._truth0
        self.pn, self.pe, self.pd = tr.pos_ned_m[0] - p0[0], tr.pos_ned_m[1] - p0[1], tr.pos_ned_m[2] - p0[2]
        self.vn, self.ve, self.vd = tr.vel_ned_m_s
        self.q = tr.quat
        self.rates = tr.rates_body_rad_s
        self.accel_body = frame.imu.accel_body_m_s2
        self.gps = frame.gps if frame.gps is not None else self.gps
        self.att_valid = self.pos_valid = self.height_valid = self.ref_alt_valid = True
        self.gps_good_since_ns = -GPS_CHECK_NS
        self.last_gps_ns = self.last_baro_ns = self.last_mag_ns = self.last_imu_ns = frame.t_ns
