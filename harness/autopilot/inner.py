"""The per-tick inner loop, modelled on PX4's controllers and compiled with numba (``harness.core.jit``):
attitude P on the quaternion (tilt before yaw, ``MC_YAW_WEIGHT``) → body-rate PID → quad-X mixer (yaw gives
way first) → thrust model (``THR_MDL_FAC``).

``inner_loop`` runs all four in one compiled call; ``AttitudeControl``, ``RateControl`` and ``mix_quad_x`` are
the same kernels one stage at a time. Every kernel that ``inner_loop`` calls is in this module: numba's cache
notices a change of the calling kernel's own file only.
"""

from __future__ import annotations

import math

from harness.autopilot.params import Params
from harness.core.geo import Quat
from harness.core.jit import Floats, callee, floats, kernel

# ---- attitude control ----
# gains g: MC_ROLL_P, MC_PITCH_P, MC_YAW_P, MC_YAW_WEIGHT, max roll, pitch, yaw rate (rad/s)


@callee
def attitude_rates(
    g: Floats,
    w: float,
    x: float,
    y: float,
    z: float,
    dw: float,
    dx: float,
    dy: float,
    dz: float,
    yaw_rate_ff: float,
) -> tuple[float, float, float]:
    """Quaternion attitude P: body-rate setpoint turning attitude (w, x, y, z) towards (dw, dx, dy, dz)."""
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
    a = g[3]
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
    rr = g[0] * s * erx
    rp = g[1] * s * ery
    ry = g[2] * s * erz / (a if a > 1e-3 else 1e-3)
    if yaw_rate_ff != 0.0:
        # feed-forward about the world z axis, expressed in body axes
        rr += yaw_rate_ff * ex
        rp += yaw_rate_ff * ey
        ry += yaw_rate_ff * ez
    mr, mp, my = g[4], g[5], g[6]
    rr = -mr if rr < -mr else (mr if rr > mr else rr)
    rp = -mp if rp < -mp else (mp if rp > mp else rp)
    ry = -my if ry < -my else (my if ry > my else ry)
    return (rr, rp, ry)


class AttitudeControl:
    """Quaternion attitude P (PX4): tilt is corrected with full authority, yaw with ``MC_YAW_WEIGHT``."""

    def __init__(self, params: Params) -> None:
        self.params = params
        self._ver = -1
        self.gains = floats([0.0] * 7)
        """MC_ROLL_P, MC_PITCH_P, MC_YAW_P, MC_YAW_WEIGHT, the roll, pitch and yaw rate limits (rad/s)."""
        self._load()

    def _load(self) -> None:
        p = self.params
        self._ver = p.version
        self.gains[:] = (
            p["MC_ROLL_P"],
            p["MC_PITCH_P"],
            p["MC_YAW_P"],
            p["MC_YAW_WEIGHT"],
            math.radians(p["MC_ROLLRATE_MAX"]),
            math.radians(p["MC_PITCHRATE_MAX"]),
            math.radians(p["MC_YAWRATE_MAX"]),
        )

    def refresh(self) -> None:
        """Re-read the gains if a parameter changed."""
        if self.params.version != self._ver:
            self._load()

    def update(self, q: Quat, qd: Quat, yaw_rate_ff: float = 0.0) -> tuple[float, float, float]:
        self.refresh()
        return attitude_rates(self.gains, *q, *qd, yaw_rate_ff)


# ---- rate control ----
# gains g: P (roll, pitch, yaw), I (3), D (3), integrator limits (3)
# state s: integrators (3), previous rates (3), mixer saturation flags of the last tick: positive (3), negative (3)


@callee
def rate_pid(
    g: Floats,
    s: Floats,
    sp0: float,
    sp1: float,
    sp2: float,
    p0: float,
    p1: float,
    p2: float,
    dt: float,
    sat_pos0: bool,
    sat_pos1: bool,
    sat_pos2: bool,
    sat_neg0: bool,
    sat_neg1: bool,
    sat_neg2: bool,
    integrate: bool,
) -> tuple[float, float, float]:
    """Body-rate PID (D on the measurement); integrators and previous rates in ``s`` updated."""
    e0, e1, e2 = sp0 - p0, sp1 - p1, sp2 - p2
    inv = 1.0 / dt if dt > 0.0 else 0.0
    out = (
        g[0] * e0 + s[0] - g[6] * (p0 - s[3]) * inv,
        g[1] * e1 + s[1] - g[7] * (p1 - s[4]) * inv,
        g[2] * e2 + s[2] - g[8] * (p2 - s[5]) * inv,
    )
    if integrate:
        if not ((sat_pos0 and e0 > 0.0) or (sat_neg0 and e0 < 0.0)):
            v, lim = s[0] + g[3] * e0 * dt, g[9]
            s[0] = -lim if v < -lim else (lim if v > lim else v)
        if not ((sat_pos1 and e1 > 0.0) or (sat_neg1 and e1 < 0.0)):
            v, lim = s[1] + g[4] * e1 * dt, g[10]
            s[1] = -lim if v < -lim else (lim if v > lim else v)
        if not ((sat_pos2 and e2 > 0.0) or (sat_neg2 and e2 < 0.0)):
            v, lim = s[2] + g[5] * e2 * dt, g[11]
            s[2] = -lim if v < -lim else (lim if v > lim else v)
    s[3], s[4], s[5] = p0, p1, p2
    return out


class RateControl:
    """Body-rate PID with integrator anti-windup driven by the mixer's saturation flags."""

    def __init__(self, params: Params) -> None:
        self.params = params
        self._ver = -1
        self.gains = floats([0.0] * 12)
        self.state = floats([0.0] * 12)
        """Integrators (3), previous rates (3), the mixer's last saturation flags (positive 3, negative 3)."""
        self._load()

    def _load(self) -> None:
        p = self.params
        self._ver = p.version
        self.gains[:] = (
            p["MC_ROLLRATE_P"],
            p["MC_PITCHRATE_P"],
            p["MC_YAWRATE_P"],
            p["MC_ROLLRATE_I"],
            p["MC_PITCHRATE_I"],
            p["MC_YAWRATE_I"],
            p["MC_ROLLRATE_D"],
            p["MC_PITCHRATE_D"],
            p["MC_YAWRATE_D"],
            p["MC_RR_INT_LIM"],
            p["MC_PR_INT_LIM"],
            p["MC_YR_INT_LIM"],
        )

    def refresh(self) -> None:
        """Re-read the gains if a parameter changed."""
        if self.params.version != self._ver:
            self._load()

    @property
    def i(self) -> tuple[float, float, float]:
        """The integrators (roll, pitch, yaw)."""
        s = self.state
        return (float(s[0]), float(s[1]), float(s[2]))

    def reset(self) -> None:
        s = self.state
        s[0] = s[1] = s[2] = 0.0

    def update(
        self,
        rates_sp: tuple[float, float, float],
        rates: tuple[float, float, float],
        dt: float,
        sat_pos: tuple[bool, bool, bool] = (False, False, False),
        sat_neg: tuple[bool, bool, bool] = (False, False, False),
        integrate: bool = True,
    ) -> tuple[float, float, float]:
        self.refresh()
        return rate_pid(self.gains, self.state, *rates_sp, *rates, dt, *sat_pos, *sat_neg, integrate)


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
Motors = tuple[float, float, float, float]


@callee
def _max4(a: float, b: float, c: float, d: float) -> float:
    """``max(a, b, c, d)``: the first of the largest, as the builtin (an argument replaces only a smaller one)."""
    if b > a:
        a = b
    if c > a:
        a = c
    return d if d > a else a


@callee
def _min4(a: float, b: float, c: float, d: float) -> float:
    """``min(a, b, c, d)``, as the builtin."""
    if b < a:
        a = b
    if c < a:
        a = c
    return d if d < a else a


@callee
def mix(
    roll: float, pitch: float, yaw: float, thrust: float, idle: float
) -> tuple[float, float, float, float, bool, bool, bool, bool, bool, bool]:
    """The quad-X mixer (see ``mix_quad_x``): motors 0-3, saturated positive (3), saturated negative (3)."""
    a = _K * (pitch - roll)  # motor 0 and, negated, motor 1
    b = _K * (pitch + roll)  # motor 2 and, negated, motor 3
    m0, m1, m2, m3 = thrust + a, thrust - a, thrust + b, thrust - b
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
        0.0 if m0 < 0.0 else (1.0 if m0 > 1.0 else m0),
        0.0 if m1 < 0.0 else (1.0 if m1 > 1.0 else m1),
        0.0 if m2 < 0.0 else (1.0 if m2 > 1.0 else m2),
        0.0 if m3 < 0.0 else (1.0 if m3 > 1.0 else m3),
        rp_sat and roll > 0.0,
        rp_sat and pitch > 0.0,
        yaw > y + 1e-9,
        rp_sat and roll < 0.0,
        rp_sat and pitch < 0.0,
        yaw < y - 1e-9,
    )


def mix_quad_x(roll: float, pitch: float, yaw: float, thrust: float, idle: float = 0.0) -> tuple[Motors, Sat, Sat]:
    """Quad-X mixer with saturation handling: roll/pitch first (thrust shifted, then scaled), yaw last.

    Returns (motors in [idle, 1], saturated-positive per axis, saturated-negative per axis); a saturated
    axis asked for more torque than it got (the rate integrators stop growing that way). Yaw gets only the
    room that roll, pitch and thrust leave ("yaw gives way first").
    """
    m0, m1, m2, m3, p0, p1, p2, n0, n1, n2 = mix(roll, pitch, yaw, thrust, idle)
    return (m0, m1, m2, m3), (p0, p1, p2), (n0, n1, n2)


@callee
def thrust_model(m: float, fac: float) -> float:
    """The motor command giving normalised thrust ``m``: the inverse of thrust = f u² + (1 - f) u (``THR_MDL_FAC``)."""
    if fac == 1.0:
        return math.sqrt(m)
    if fac > 0.0:
        a = 1.0 - fac
        return (math.sqrt(a * a + 4.0 * fac * m) - a) / (2.0 * fac)
    return m


# ---- the per-tick cascade in one call ----
@kernel
def inner_loop(
    att_g: Floats,
    rate_g: Floats,
    rate_s: Floats,
    use_att: bool,
    w: float,
    x: float,
    y: float,
    z: float,
    dw: float,
    dx: float,
    dy: float,
    dz: float,
    yaw_rate_ff: float,
    add_rates: bool,
    br0: float,
    br1: float,
    br2: float,
    p0: float,
    p1: float,
    p2: float,
    thrust: float,
    dt: float,
    integrate: bool,
    idle: float,
    fac: float,
) -> Motors:
    """Attitude P (when ``use_att``; body rates ``br`` added when ``add_rates``, or alone without attitude)
    → rate PID (anti-windup by the mixer's flags of the last tick, kept in ``rate_s``) → mixer → thrust model."""
    if use_att:
        r0, r1, r2 = attitude_rates(att_g, w, x, y, z, dw, dx, dy, dz, yaw_rate_ff)
        if add_rates:
            r0, r1, r2 = r0 + br0, r1 + br1, r2 + br2
    else:
        r0, r1, r2 = br0, br1, br2
    s = rate_s
    t0, t1, t2 = rate_pid(
        rate_g, s, r0, r1, r2, p0, p1, p2, dt, s[6] != 0.0, s[7] != 0.0, s[8] != 0.0,
        s[9] != 0.0, s[10] != 0.0, s[11] != 0.0, integrate,
    )  # fmt: skip
    m0, m1, m2, m3, s[6], s[7], s[8], s[9], s[10], s[11] = mix(t0, t1, t2, thrust, idle)
    return (thrust_model(m0, fac), thrust_model(m1, fac), thrust_model(m2, fac), thrust_model(m3, fac))
