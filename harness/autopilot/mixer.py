"""The quad-X mixer and the motors' thrust model, compiled with numba (``harness.core.jit``).

The mixer turns the rate controller's torques and the collective thrust into four normalised motor thrusts
with PX4's saturation handling (roll and pitch first, yaw gives way); the thrust model turns a normalised
thrust into the motor command (``THR_MDL_FAC``). ``control.inner_loop`` calls both in its one compiled call.
"""

from __future__ import annotations

import math

from harness.core.jit import kernel

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


@kernel
def _max4(a: float, b: float, c: float, d: float) -> float:
    """``max(a, b, c, d)``: the first of the largest, as the builtin (an argument replaces only a smaller one)."""
    if b > a:
        a = b
    if c > a:
        a = c
    return d if d > a else a


@kernel
def _min4(a: float, b: float, c: float, d: float) -> float:
    """``min(a, b, c, d)``, as the builtin."""
    if b < a:
        a = b
    if c < a:
        a = c
    return d if d < a else a


@kernel
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


@kernel
def thrust_model(m: float, fac: float) -> float:
    """The motor command giving normalised thrust ``m``: the inverse of thrust = f u² + (1 - f) u (``THR_MDL_FAC``)."""
    if fac == 1.0:
        return math.sqrt(m)
    if fac > 0.0:
        a = 1.0 - fac
        return (math.sqrt(a * a + 4.0 * fac * m) - a) / (2.0 * fac)
    return m
