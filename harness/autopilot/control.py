"""The multicopter control cascade, modelled on PX4's controllers, in plain float math.

position P → velocity PID (+ acceleration feed-forward) → thrust vector → attitude setpoint (quaternion)
→ attitude P (tilt before yaw, ``MC_YAW_WEIGHT``) → body-rate PID → quad-X mixer (yaw gives way first).

Gains are the PX4 parameters (``MPC_*``, ``MC_*``); each controller re-reads them when the parameter
registry's version changes.
"""

from __future__ import annotations

import math

from harness.autopilot.mathutil import G_M_S2
from harness.autopilot.params import Params
from harness.core.geo import Quat

NAN = math.nan
_isnan = math.isnan


class TrajectorySetpoint:
    """What a flight mode asks of the position controller (PX4's trajectory setpoint); NaN = unset.

    Position given → velocity = P·error + velocity (as feed-forward); position NaN → velocity alone.
    """

    __slots__ = ("ax", "ay", "az", "px", "py", "pz", "vx", "vy", "vz", "yaw", "yaw_rate")

    def __init__(self) -> None:
        self.px = self.py = self.pz = NAN
        self.vx = self.vy = self.vz = NAN
        self.ax = self.ay = self.az = NAN
        self.yaw = NAN
        self.yaw_rate = NAN

    def set(
        self,
        pos: tuple[float, float, float] = (NAN, NAN, NAN),
        vel: tuple[float, float, float] = (NAN, NAN, NAN),
        acc: tuple[float, float, float] = (NAN, NAN, NAN),
        yaw: float = NAN,
        yaw_rate: float = NAN,
    ) -> None:
        self.px, self.py, self.pz = pos
        self.vx, self.vy, self.vz = vel
        self.ax, self.ay, self.az = acc
        self.yaw = yaw
        self.yaw_rate = yaw_rate


class PositionControl:
    """Position P and velocity PID; output a thrust vector in NED (normalised thrust units)."""

    def __init__(self, params: Params) -> None:
        self.params = params
        self._ver = -1
        self.ix = self.iy = 0.0
        self.iz = 0.0
        self.xy_vel_max = params["MPC_XY_VEL_MAX"]
        self.hover = params["MPC_THR_HOVER"]
        """Hover thrust in use (the flight core updates it from its in-flight estimate)."""
        self.thr = (0.0, 0.0, -params["MPC_THR_HOVER"])
        self.vel_sp = (0.0, 0.0, 0.0)
        self.acc_z = 0.0
        """Last vertical acceleration setpoint (NED, m/s²)."""
        self._load()

    def _load(self) -> None:
        p = self.params
        self._ver = p.version
        self.kp_xy, self.kp_z = p["MPC_XY_P"], p["MPC_Z_P"]
        self.kv_xy, self.ki_xy, self.kd_xy = p["MPC_XY_VEL_P_ACC"], p["MPC_XY_VEL_I_ACC"], p["MPC_XY_VEL_D_ACC"]
        self.kv_z, self.ki_z, self.kd_z = p["MPC_Z_VEL_P_ACC"], p["MPC_Z_VEL_I_ACC"], p["MPC_Z_VEL_D_ACC"]
        self.vel_up, self.vel_dn = p["MPC_Z_VEL_MAX_UP"], p["MPC_Z_VEL_MAX_DN"]
        self.thr_min, self.thr_max = p["MPC_THR_MIN"], p["MPC_THR_MAX"]
        self.tilt_max = math.radians(p["MPC_TILTMAX_AIR"])
        self._cos_tilt_max = math.cos(self.tilt_max)
        self._sin_tilt_max = math.sqrt(1.0 - self._cos_tilt_max * self._cos_tilt_max)
        self.acc_hor_max = p["MPC_ACC_HOR_MAX"]

    def reset(self) -> None:
        self.ix = self.iy = self.iz = 0.0

    def set_hover(self, hover: float) -> None:
        """Change the hover thrust keeping the thrust output continuous (as PX4's updateHoverThrust)."""
        if hover <= 0.0 or hover == self.hover:
            return
        a = self.acc_z
        a_new = (a - G_M_S2) * self.hover / hover + G_M_S2
        self.iz += a_new - a
        self.acc_z = a_new
        self.hover = hover

    def update(
        self,
        sp: TrajectorySetpoint,
        pos: tuple[float, float, float],
        vel: tuple[float, float, float],
        dt: float,
    ) -> tuple[float, float, float]:
        if self.params.version != self._ver:
            self._load()
        pn, pe, pd = pos
        vn, ve, vd = vel
        # position P -> velocity setpoint (feed-forward added)
        vx = 0.0 if _isnan(sp.vx) else sp.vx
        vy = 0.0 if _isnan(sp.vy) else sp.vy
        vz = 0.0 if _isnan(sp.vz) else sp.vz
        if not _isnan(sp.px):
            vx += self.kp_xy * (sp.px - pn)
            vy += self.kp_xy * (sp.py - pe)
        elif _isnan(sp.vx):
            vx, vy = vn, ve  # acceleration only: no horizontal velocity error
        if not _isnan(sp.pz):
            vz += self.kp_z * (sp.pz - pd)
        elif _isnan(sp.vz):
            vz = vd
        h = math.sqrt(vx * vx + vy * vy)
        lim = self.xy_vel_max
        if h > lim:
            vx *= lim / h
            vy *= lim / h
        vz = -self.vel_up if vz < -self.vel_up else (self.vel_dn if vz > self.vel_dn else vz)
        self.vel_sp = (vx, vy, vz)
        # velocity PID -> acceleration setpoint
        ex, ey, ez = vx - vn, vy - ve, vz - vd
        ax = self.kv_xy * ex + self.ix + (0.0 if _isnan(sp.ax) else sp.ax)
        ay = self.kv_xy * ey + self.iy + (0.0 if _isnan(sp.ay) else sp.ay)
        az = self.kv_z * ez + self.iz + (0.0 if _isnan(sp.az) else sp.az)
        ah = math.sqrt(ax * ax + ay * ay)
        if ah > self.acc_hor_max:
            ax *= self.acc_hor_max / ah
            ay *= self.acc_hor_max / ah
        self.acc_z = az
        # acceleration -> thrust vector (PX4: body z from the tilt, collective from the vertical part)
        bx, by, bz = -ax, -ay, G_M_S2
        bn = math.sqrt(bx * bx + by * by + bz * bz)
        bx, by, bz = bx / bn, by / bn, bz / bn
        cos_max = self._cos_tilt_max
        if bz < cos_max:
            s = self._sin_tilt_max / math.sqrt(bx * bx + by * by)
            bx, by, bz = bx * s, by * s, cos_max
        hov = self.hover
        coll = (az * (hov / G_M_S2) - hov) / bz
        sat_lo = coll > -self.thr_min
        if sat_lo:
            coll = -self.thr_min
        tx, ty, tz = bx * coll, by * coll, bz * coll
        # keep vertical thrust priority: limit the horizontal part to what is left below thr_max
        sat_hi = False
        if -tz > self.thr_max:
            tz = -self.thr_max
            sat_hi = True
        th = math.sqrt(tx * tx + ty * ty)
        room = math.sqrt(max(self.thr_max * self.thr_max - tz * tz, 0.0))
        if th > room:
            tx *= room / th
            ty *= room / th
        # integrators with anti-windup
        if not ((sat_hi and ez < 0.0) or (sat_lo and ez > 0.0)):
            self.iz += self.ki_z * ez * dt
            lim_i = G_M_S2
            self.iz = -lim_i if self.iz < -lim_i else (lim_i if self.iz > lim_i else self.iz)
        if th <= room and ah <= self.acc_hor_max:
            # integrate a bounded error: a large step (offboard velocity) does not wind the integrator up
            en = math.sqrt(ex * ex + ey * ey)
            k = self.ki_xy * dt * (1.0 if en <= 0.5 else 0.5 / en)
            self.ix += k * ex
            self.iy += k * ey
            ih = math.sqrt(self.ix * self.ix + self.iy * self.iy)
            if ih > 3.0:
                self.ix *= 3.0 / ih
                self.iy *= 3.0 / ih
        self.thr = (tx, ty, tz)
        return self.thr


def thrust_to_attitude(thr: tuple[float, float, float], yaw: float) -> tuple[Quat, float]:
    """PX4's bodyzToAttitude: the attitude whose body z opposes the thrust vector with the given yaw."""
    tx, ty, tz = thr
    n = math.sqrt(tx * tx + ty * ty + tz * tz)
    if n < 1e-6:
        zx, zy, zz = 0.0, 0.0, 1.0
    else:
        zx, zy, zz = -tx / n, -ty / n, -tz / n
    cy, sy = math.cos(yaw), math.sin(yaw)
    # y_C = (-sin yaw, cos yaw, 0); body_x = y_C x body_z
    xx, xy, xz = cy * zz, sy * zz, -sy * zy - cy * zx
    if zz < 0.0:
        xx, xy, xz = -xx, -xy, -xz
    xn = math.sqrt(xx * xx + xy * xy + xz * xz)
    xx, xy, xz = xx / xn, xy / xn, xz / xn
    # body_y = body_z x body_x
    yx, yy, yz = zy * xz - zz * xy, zz * xx - zx * xz, zx * xy - zy * xx
    return dcm_to_quat(xx, yx, zx, xy, yy, zy, xz, yz, zz), n


def dcm_to_quat(
    r00: float, r01: float, r02: float, r10: float, r11: float, r12: float, r20: float, r21: float, r22: float
) -> Quat:
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        return (0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s)
    if r00 > r11 and r00 > r22:
        s = math.sqrt(1.0 + r00 - r11 - r22) * 2.0
        return ((r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s)
    if r11 > r22:
        s = math.sqrt(1.0 + r11 - r00 - r22) * 2.0
        return ((r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s)
    s = math.sqrt(1.0 + r22 - r00 - r11) * 2.0
    return ((r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s)


class AttitudeControl:
    """Quaternion attitude P (PX4): tilt is corrected with full authority, yaw with ``MC_YAW_WEIGHT``."""

    def __init__(self, params: Params) -> None:
        self.params = params
        self._ver = -1
        self._load()

    def _load(self) -> None:
        p = self.params
        self._ver = p.version
        self.kr, self.kp, self.ky = p["MC_ROLL_P"], p["MC_PITCH_P"], p["MC_YAW_P"]
        self.yaw_w = p["MC_YAW_WEIGHT"]
        self.max_r = math.radians(p["MC_ROLLRATE_MAX"])
        self.max_p = math.radians(p["MC_PITCHRATE_MAX"])
        self.max_y = math.radians(p["MC_YAWRATE_MAX"])

    def update(self, q: Quat, qd: Quat, yaw_rate_ff: float = 0.0) -> tuple[float, float, float]:
        if self.params.version != self._ver:
            self._load()
        w, x, y, z = q
        dw, dx, dy, dz = qd
        # body z axes in world (third column of R)
        ex, ey, ez = 2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)
        fx, fy, fz = 2 * (dx * dz + dw * dy), 2 * (dy * dz - dw * dx), 1 - 2 * (dx * dx + dy * dy)
        # shortest rotation e_z -> e_z_d, applied to q: reduced attitude setpoint
        d = ex * fx + ey * fy + ez * fz
        cx, cy, cz = ey * fz - ez * fy, ez * fx - ex * fz, ex * fy - ey * fx
        if d > -0.9999:
            rw = 1.0 + d
            rn = math.sqrt(rw * rw + cx * cx + cy * cy + cz * cz)
            rw, cx, cy, cz = rw / rn, cx / rn, cy / rn, cz / rn
            # qr = (rw, c) * q
            qrw = rw * w - cx * x - cy * y - cz * z
            qrx = rw * x + cx * w + cy * z - cz * y
            qry = rw * y - cx * z + cy * w + cz * x
            qrz = rw * z + cx * y - cy * x + cz * w
        else:
            qrw, qrx, qry, qrz = dw, dx, dy, dz
        # mix: qmix = qr^-1 * qd, keep yaw_w of its yaw part
        mw = qrw * dw + qrx * dx + qry * dy + qrz * dz
        mz = qrw * dz - qrx * dy + qry * dx - qrz * dw
        if mw < 0.0:
            mw, mz = -mw, -mz
        mw = 1.0 if mw > 1.0 else mw
        mz = -1.0 if mz < -1.0 else (1.0 if mz > 1.0 else mz)
        a = self.yaw_w
        pw, pz = math.cos(a * math.acos(mw)), math.sin(a * math.asin(mz))
        # qd' = qr * (pw, 0, 0, pz)
        sw = qrw * pw - qrz * pz
        sx = qrx * pw + qry * pz
        sy = qry * pw - qrx * pz
        sz = qrz * pw + qrw * pz
        # error qe = q^-1 * qd'
        ew = w * sw + x * sx + y * sy + z * sz
        erx = w * sx - x * sw - y * sz + z * sy
        ery = w * sy + x * sz - y * sw - z * sx
        erz = w * sz - x * sy + y * sx - z * sw
        s = 2.0 if ew >= 0.0 else -2.0
        rr = self.kr * s * erx
        rp = self.kp * s * ery
        ry = self.ky * s * erz / (a if a > 1e-3 else 1e-3)
        if yaw_rate_ff:
            # feed-forward about the world z axis, expressed in body axes
            rr += yaw_rate_ff * ex
            rp += yaw_rate_ff * ey
            ry += yaw_rate_ff * ez
        mr, mp, my = self.max_r, self.max_p, self.max_y
        rr = -mr if rr < -mr else (mr if rr > mr else rr)
        rp = -mp if rp < -mp else (mp if rp > mp else rp)
        ry = -my if ry < -my else (my if ry > my else ry)
        return (rr, rp, ry)


class RateControl:
    """Body-rate PID with integrator anti-windup driven by the mixer's saturation flags."""

    def __init__(self, params: Params) -> None:
        self.params = params
        self._ver = -1
        self.i = [0.0, 0.0, 0.0]
        self.prev = (0.0, 0.0, 0.0)
        self._load()

    def _load(self) -> None:
        p = self.params
        self._ver = p.version
        self.kp = (p["MC_ROLLRATE_P"], p["MC_PITCHRATE_P"], p["MC_YAWRATE_P"])
        self.ki = (p["MC_ROLLRATE_I"], p["MC_PITCHRATE_I"], p["MC_YAWRATE_I"])
        self.kd = (p["MC_ROLLRATE_D"], p["MC_PITCHRATE_D"], p["MC_YAWRATE_D"])
        self.ilim = (p["MC_RR_INT_LIM"], p["MC_PR_INT_LIM"], p["MC_YR_INT_LIM"])

    def reset(self) -> None:
        self.i = [0.0, 0.0, 0.0]

    def update(
        self,
        rates_sp: tuple[float, float, float],
        rates: tuple[float, float, float],
        dt: float,
        sat_pos: tuple[bool, bool, bool] = (False, False, False),
        sat_neg: tuple[bool, bool, bool] = (False, False, False),
        integrate: bool = True,
    ) -> tuple[float, float, float]:
        if self.params.version != self._ver:
            self._load()
        p0, p1, p2 = rates
        q0, q1, q2 = self.prev
        e0, e1, e2 = rates_sp[0] - p0, rates_sp[1] - p1, rates_sp[2] - p2
        (kp0, kp1, kp2), (kd0, kd1, kd2), i = self.kp, self.kd, self.i
        i0, i1, i2 = i
        inv = 1.0 / dt if dt > 0.0 else 0.0
        out = (
            kp0 * e0 + i0 - kd0 * (p0 - q0) * inv,
            kp1 * e1 + i1 - kd1 * (p1 - q1) * inv,
            kp2 * e2 + i2 - kd2 * (p2 - q2) * inv,
        )
        if integrate:
            ki, lim = self.ki, self.ilim
            for k, e in enumerate((e0, e1, e2)):
                if not ((sat_pos[k] and e > 0.0) or (sat_neg[k] and e < 0.0)):
                    v = i[k] + ki[k] * e * dt
                    i[k] = -lim[k] if v < -lim[k] else (lim[k] if v > lim[k] else v)
        self.prev = rates
        return out


# PX4 quad-X geometry, motor order as the sensor frame says: (roll, pitch, yaw) coefficients
# 0 front right CCW (-r, +p, +y), 1 rear left CCW (+r, -p, +y), 2 front left CW (+r, +p, -y), 3 rear right CW (-r, -p, -y)
QUAD_X = (
    (-0.707107, 0.707107, 1.0),
    (0.707107, -0.707107, 1.0),
    (0.707107, 0.707107, -1.0),
    (-0.707107, -0.707107, -1.0),
)
_K = 0.707107

Sat = tuple[bool, bool, bool]


def _max4(a: float, b: float, c: float, d: float) -> float:
    """``max(a, b, c, d)``: the first of the largest, as the builtin (an argument replaces only a smaller one)."""
    if b > a:
        a = b
    if c > a:
        a = c
    return d if d > a else a


def _min4(a: float, b: float, c: float, d: float) -> float:
    """``min(a, b, c, d)``, as the builtin."""
    if b < a:
        a = b
    if c < a:
        a = c
    return d if d < a else a


def mix_quad_x(
    roll: float, pitch: float, yaw: float, thrust: float, idle: float = 0.0
) -> tuple[tuple[float, float, float, float], Sat, Sat]:
    """Quad-X mixer with saturation handling: roll/pitch first (thrust shifted, then scaled), yaw last.

    Returns (motors in [idle, 1], saturated-positive per axis, saturated-negative per axis); a saturated
    axis asked for more torque than it got (the rate integrators stop growing that way). Yaw gets only the
    room that roll, pitch and thrust leave ("yaw gives way first").
    """
    a = _K * (pitch - roll)  # motor 0 and, negated, motor 1
    b = _K * (pitch + roll)  # motor 2 and, negated, motor 3
    m0, m1, m2, m3 = thrust + a, thrust - a, thrust + b, thrust - b
    # (max and min written out: the same choices as the builtins, NaN included, without their calls)
    aa, ab = abs(a), abs(b)
    span = 2.0 * (ab if ab > aa else aa)
    room = 1.0 - idle
    rp_sat = span > room
    if rp_sat:
        k = room / span
        roll *= k
        pitch *= k
        a *= k
        b *= k
        m0, m1, m2, m3 = thrust + a, thrust - a, thrust + b, thrust - b
    hi = _max4(m0, m1, m2, m3)
    lo = _min4(m0, m1, m2, m3)
    if hi > 1.0:
        d = hi - 1.0
        m0, m1, m2, m3 = m0 - d, m1 - d, m2 - d, m3 - d
    elif lo < idle:
        d = idle - lo
        m0, m1, m2, m3 = m0 + d, m1 + d, m2 + d, m3 + d
    # yaw: +y on motors 0, 1 and -y on motors 2, 3 must keep all four in [idle, 1]
    ymax = _min4(1.0 - m0, 1.0 - m1, m2 - idle, m3 - idle)
    ymin = _max4(idle - m0, idle - m1, m2 - 1.0, m3 - 1.0)
    y = (ymin if yaw < ymin else (ymax if yaw > ymax else yaw)) if ymin <= ymax else 0.0
    m0, m1, m2, m3 = m0 + y, m1 + y, m2 - y, m3 - y
    return (
        (
            0.0 if m0 < 0.0 else (1.0 if m0 > 1.0 else m0),
            0.0 if m1 < 0.0 else (1.0 if m1 > 1.0 else m1),
            0.0 if m2 < 0.0 else (1.0 if m2 > 1.0 else m2),
            0.0 if m3 < 0.0 else (1.0 if m3 > 1.0 else m3),
        ),
        (rp_sat and roll > 0.0, rp_sat and pitch > 0.0, yaw > y + 1e-9),
        (rp_sat and roll < 0.0, rp_sat and pitch < 0.0, yaw < y - 1e-9),
    )
