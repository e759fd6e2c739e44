"""The multicopter control cascade's outer part, modelled on PX4's controllers, compiled with numba.

position P → velocity PID (+ acceleration feed-forward) → thrust vector → attitude setpoint (quaternion);
the inner loop (attitude P → body-rate PID → quad-X mixer) is ``inner.py``.

Gains are the PX4 parameters (``MPC_*``); the controller copies them into a float64 array when the parameter
registry's version changes. The equations are the ``@kernel`` functions below (numba, see
``harness.core.jit``): each stage is one compiled call over floats, the gains array and the controller's
state array (integrators, hover thrust), which the kernel mutates in place; ``PositionControl`` is the
Python interface the flight core and the tests use.
"""

from __future__ import annotations

import math

from harness.autopilot.mathutil import G_M_S2
from harness.autopilot.params import Params
from harness.core.geo import Quat
from harness.core.jit import Floats, callee, compiled, floats, kernel

NAN = math.nan


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


# ---- position control ----
# gains g: kp_xy, kp_z, kv_xy, ki_xy, kv_z, ki_z, vel_up, vel_dn, thr_min, thr_max, cos_tilt_max,
#          sin_tilt_max, acc_hor_max, xy_vel_max
# state s: ix, iy, iz, acc_z (last vertical acceleration setpoint, NED m/s²), hover (hover thrust in use)
_IX, _IY, _IZ, _ACC_Z, _HOVER = range(5)


@kernel
def position_step(
    g: Floats,
    s: Floats,
    spx: float,
    spy: float,
    spz: float,
    svx: float,
    svy: float,
    svz: float,
    sax: float,
    say: float,
    saz: float,
    pn: float,
    pe: float,
    pd: float,
    vn: float,
    ve: float,
    vd: float,
    dt: float,
) -> tuple[float, float, float, float, float, float]:
    """Position P and velocity PID, integrators in ``s`` updated; returns (velocity setpoint, thrust vector)."""
    kp_xy, kp_z, kv_xy, ki_xy, kv_z, ki_z = g[0], g[1], g[2], g[3], g[4], g[5]
    vel_up, vel_dn, thr_min, thr_max = g[6], g[7], g[8], g[9]
    cos_max, sin_max, acc_hor_max, lim = g[10], g[11], g[12], g[13]
    # position P -> velocity setpoint (feed-forward added)
    vx = 0.0 if math.isnan(svx) else svx
    vy = 0.0 if math.isnan(svy) else svy
    vz = 0.0 if math.isnan(svz) else svz
    if not math.isnan(spx):
        vx += kp_xy * (spx - pn)
        vy += kp_xy * (spy - pe)
    elif math.isnan(svx):
        vx, vy = vn, ve  # acceleration only: no horizontal velocity error
    if not math.isnan(spz):
        vz += kp_z * (spz - pd)
    elif math.isnan(svz):
        vz = vd
    h = math.sqrt(vx * vx + vy * vy)
    if h > lim:
        vx *= lim / h
        vy *= lim / h
    vz = -vel_up if vz < -vel_up else (vel_dn if vz > vel_dn else vz)
    # velocity PID -> acceleration setpoint
    ex, ey, ez = vx - vn, vy - ve, vz - vd
    ax = kv_xy * ex + s[_IX] + (0.0 if math.isnan(sax) else sax)
    ay = kv_xy * ey + s[_IY] + (0.0 if math.isnan(say) else say)
    az = kv_z * ez + s[_IZ] + (0.0 if math.isnan(saz) else saz)
    ah = math.sqrt(ax * ax + ay * ay)
    if ah > acc_hor_max:
        ax *= acc_hor_max / ah
        ay *= acc_hor_max / ah
    s[_ACC_Z] = az
    # acceleration -> thrust vector (PX4: body z from the tilt, collective from the vertical part)
    bx, by, bz = -ax, -ay, G_M_S2
    bn = math.sqrt(bx * bx + by * by + bz * bz)
    bx, by, bz = bx / bn, by / bn, bz / bn
    if bz < cos_max:
        k = sin_max / math.sqrt(bx * bx + by * by)
        bx, by, bz = bx * k, by * k, cos_max
    hov = s[_HOVER]
    coll = (az * (hov / G_M_S2) - hov) / bz
    sat_lo = coll > -thr_min
    if sat_lo:
        coll = -thr_min
    tx, ty, tz = bx * coll, by * coll, bz * coll
    # keep vertical thrust priority: limit the horizontal part to what is left below thr_max
    sat_hi = False
    if -tz > thr_max:
        tz = -thr_max
        sat_hi = True
    th = math.sqrt(tx * tx + ty * ty)
    r2 = thr_max * thr_max - tz * tz
    room = math.sqrt(0.0 if r2 < 0.0 else r2)
    if th > room:
        tx *= room / th
        ty *= room / th
    # integrators with anti-windup
    if not ((sat_hi and ez < 0.0) or (sat_lo and ez > 0.0)):
        iz = s[_IZ] + ki_z * ez * dt
        s[_IZ] = -G_M_S2 if iz < -G_M_S2 else (G_M_S2 if iz > G_M_S2 else iz)
    if th <= room and ah <= acc_hor_max:
        # integrate a bounded error: a large step (offboard velocity) does not wind the integrator up
        en = math.sqrt(ex * ex + ey * ey)
        k = ki_xy * dt * (1.0 if en <= 0.5 else 0.5 / en)
        ix = s[_IX] + k * ex
        iy = s[_IY] + k * ey
        ih = math.sqrt(ix * ix + iy * iy)
        if ih > 3.0:
            ix *= 3.0 / ih
            iy *= 3.0 / ih
        s[_IX], s[_IY] = ix, iy
    return (vx, vy, vz, tx, ty, tz)


@kernel
def change_hover(s: Floats, hover: float) -> None:
    """Hover thrust ``hover`` in the position state ``s``, the vertical integrator moved so that the thrust
    output stays continuous (as PX4's updateHoverThrust)."""
    old = s[_HOVER]
    if hover <= 0.0 or hover == old:
        return
    a = s[_ACC_Z]
    a_new = (a - G_M_S2) * old / hover + G_M_S2
    s[_IZ] += a_new - a
    s[_ACC_Z] = a_new
    s[_HOVER] = hover


_position_step = compiled(position_step)
_change_hover = compiled(change_hover)


class PositionControl:
    """Position P and velocity PID; output a thrust vector in NED (normalised thrust units)."""

    def __init__(self, params: Params) -> None:
        self.params = params
        self._ver = -1
        self._g = floats([0.0] * 14)
        self._s = floats([0.0] * 5)
        self._g[13] = params["MPC_XY_VEL_MAX"]
        self._s[_HOVER] = params["MPC_THR_HOVER"]
        self.thr = (0.0, 0.0, -params["MPC_THR_HOVER"])
        self.vel_sp = (0.0, 0.0, 0.0)
        self._load()

    def _load(self) -> None:
        p = self.params
        self._ver = p.version
        cos_tilt = math.cos(math.radians(p["MPC_TILTMAX_AIR"]))
        self._g[:13] = (
            p["MPC_XY_P"],
            p["MPC_Z_P"],
            p["MPC_XY_VEL_P_ACC"],
            p["MPC_XY_VEL_I_ACC"],
            p["MPC_Z_VEL_P_ACC"],
            p["MPC_Z_VEL_I_ACC"],
            p["MPC_Z_VEL_MAX_UP"],
            p["MPC_Z_VEL_MAX_DN"],
            p["MPC_THR_MIN"],
            p["MPC_THR_MAX"],
            cos_tilt,
            math.sqrt(1.0 - cos_tilt * cos_tilt),
            p["MPC_ACC_HOR_MAX"],
        )

    @property
    def ix(self) -> float:
        return float(self._s[_IX])

    @ix.setter
    def ix(self, v: float) -> None:
        self._s[_IX] = v

    @property
    def iy(self) -> float:
        return float(self._s[_IY])

    @iy.setter
    def iy(self, v: float) -> None:
        self._s[_IY] = v

    @property
    def iz(self) -> float:
        return float(self._s[_IZ])

    @property
    def acc_z(self) -> float:
        """Last vertical acceleration setpoint (NED, m/s²)."""
        return float(self._s[_ACC_Z])

    @property
    def hover(self) -> float:
        """Hover thrust in use (the flight core updates it from its in-flight estimate)."""
        return float(self._s[_HOVER])

    @hover.setter
    def hover(self, v: float) -> None:
        self._s[_HOVER] = v

    @property
    def xy_vel_max(self) -> float:
        """Horizontal velocity limit, m/s (``MPC_XY_VEL_MAX`` when the controller was made)."""
        return float(self._g[13])

    def reset(self) -> None:
        self._s[_IX] = self._s[_IY] = self._s[_IZ] = 0.0

    def set_hover(self, hover: float) -> None:
        """Change the hover thrust keeping the thrust output continuous (as PX4's updateHoverThrust)."""
        _change_hover(self._s, hover)

    def update(
        self,
        sp: TrajectorySetpoint,
        pos: tuple[float, float, float],
        vel: tuple[float, float, float],
        dt: float,
    ) -> tuple[float, float, float]:
        if self.params.version != self._ver:
            self._load()
        vx, vy, vz, tx, ty, tz = _position_step(
            self._g, self._s, sp.px, sp.py, sp.pz, sp.vx, sp.vy, sp.vz, sp.ax, sp.ay, sp.az, *pos, *vel, dt
        )
        self.vel_sp = (vx, vy, vz)
        self.thr = (tx, ty, tz)
        return self.thr


# ---- thrust vector -> attitude ----
@callee
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


@kernel
def thrust_attitude(tx: float, ty: float, tz: float, yaw: float) -> tuple[float, float, float, float, float]:
    """PX4's bodyzToAttitude: (quaternion, |thrust|) of the attitude whose body z opposes the thrust."""
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
    qw, qx, qy, qz = dcm_to_quat(xx, yx, zx, xy, yy, zy, xz, yz, zz)
    return (qw, qx, qy, qz, n)


def thrust_to_attitude(thr: tuple[float, float, float], yaw: float) -> tuple[Quat, float]:
    """PX4's bodyzToAttitude: the attitude whose body z opposes the thrust vector with the given yaw."""
    qw, qx, qy, qz, n = thrust_attitude(thr[0], thr[1], thr[2], yaw)
    return (qw, qx, qy, qz), n
