"""Smooth setpoints for the auto modes: a point tracker with speed and acceleration limits, and yaw slewing.

The tracker moves a setpoint (position + velocity) straight towards a target, accelerating at most
``acc`` and braking so that it stops on the target (speed ≤ sqrt(2·acc·distance)). Horizontal and vertical
motion have separate limits. Straight legs between waypoints therefore stay on the line between them.
"""

from __future__ import annotations

import math

from harness.autopilot.mathutil import wrap_pi


class PointTracker:
    __slots__ = ("ax", "ay", "az", "vx", "vy", "vz", "x", "y", "z")

    def __init__(self) -> None:
        self.x = self.y = self.z = 0.0
        self.vx = self.vy = self.vz = 0.0
        self.ax = self.ay = self.az = 0.0

    def reset(self, pos: tuple[float, float, float], vel: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        self.x, self.y, self.z = pos
        self.vx, self.vy, self.vz = vel
        self.ax = self.ay = self.az = 0.0

    def step(
        self,
        tx: float,
        ty: float,
        tz: float,
        v_xy: float,
        v_up: float,
        v_dn: float,
        a_xy: float,
        a_z: float,
        dt: float,
    ) -> None:
        # horizontal
        dx, dy = tx - self.x, ty - self.y
        dist = math.sqrt(dx * dx + dy * dy)
        if dist > 1e-6:
            speed = min(v_xy, math.sqrt(2.0 * a_xy * dist))
            wx, wy = dx / dist * speed, dy / dist * speed
        else:
            wx = wy = 0.0
        cx, cy = wx - self.vx, wy - self.vy
        c = math.sqrt(cx * cx + cy * cy)
        lim = a_xy * dt
        if c > lim:
            cx, cy = cx * lim / c, cy * lim / c
        self.ax, self.ay = cx / dt, cy / dt
        self.vx += cx
        self.vy += cy
        step = math.sqrt(self.vx * self.vx + self.vy * self.vy) * dt
        if dist <= step or (dist < 1e-3 and step < 1e-3):
            self.x, self.y = tx, ty
            if dist <= a_xy * dt * dt:
                self.vx = self.vy = 0.0
                self.ax = self.ay = 0.0
        else:
            self.x += self.vx * dt
            self.y += self.vy * dt
        # vertical (down positive)
        dz = tz - self.z
        vmax = v_dn if dz > 0 else v_up
        want = math.copysign(min(vmax, math.sqrt(2.0 * a_z * abs(dz))), dz) if abs(dz) > 1e-6 else 0.0
        cz = want - self.vz
        lim = a_z * dt
        cz = -lim if cz < -lim else (lim if cz > lim else cz)
        self.az = cz / dt
        self.vz += cz
        if abs(dz) <= abs(self.vz) * dt:
            self.z = tz
            if abs(dz) <= a_z * dt * dt:
                self.vz = 0.0
                self.az = 0.0
        else:
            self.z += self.vz * dt


def slew_yaw(current: float, target: float, max_rate: float, dt: float) -> tuple[float, float]:
    """Move ``current`` towards ``target`` at most ``max_rate``; returns (new yaw, yaw rate used)."""
    err = wrap_pi(target - current)
    step = max_rate * dt
    if abs(err) <= step:
        return target, err / dt if dt > 0 else 0.0
    d = math.copysign(step, err)
    return wrap_pi(current + d), d / dt
