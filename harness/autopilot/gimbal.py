"""The autopilot's ``gimbal`` service: a 2-axis camera gimbal as PX4 SITL's gimbal model has one, moved in
lockstep on sim time (the MAVLink gimbal manager, ``harness.autopilot.mavlink.gimbal``, speaks for it).

Its frame is the one of PX4's GIMBAL_DEVICE_ATTITUDE_STATUS with ``GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME``:
roll and pitch earth-stabilised (roll held level: the device has no roll axis), yaw relative to the vehicle's
heading. It moves at most ``SLEW_DEG_S`` per axis towards its target (or at the commanded rates), within pitch
[-90, +30] deg and yaw [-180, +180] deg around the heading; with the yaw lock the yaw target is held in the
earth frame as the vehicle turns; a region of interest is tracked as the vehicle moves. Nothing of it touches
the flight.

A gimbal nobody has used costs one test per step: ``Autopilot.step`` moves it (``step``) once it is ``used``,
and only then does ``report`` — what END-TICK-AC carries for the recordings — hold its attitude.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from harness.autopilot.api import CommandResult, GimbalAttitude

if TYPE_CHECKING:  # not at run time: the MAVLink package imports this module before a process chooses whether
    # to compile the estimator's kernels (``harness.core.jit.prefer``), which importing it would decide
    from harness.autopilot.estimator import Estimator
    from harness.autopilot.supervisor import Commander

PITCH_MIN, PITCH_MAX = -90.0, 30.0
YAW_MIN, YAW_MAX = -180.0, 180.0
SLEW_DEG_S = 90.0


def clamp(v: float, lo: float, hi: float) -> float:
    return max(lo, min(hi, v))


def wrap180(deg: float) -> float:
    return (deg + 180.0) % 360.0 - 180.0


@dataclass(slots=True)
class GimbalState:
    """The device (degrees; yaw relative to the vehicle's heading) and what it is asked to do."""

    pitch_deg: float = 0.0
    yaw_deg: float = 0.0
    pitch_rate_deg_s: float = 0.0
    yaw_rate_deg_s: float = 0.0
    target_pitch_deg: float | None = 0.0
    target_yaw_deg: float | None = 0.0
    """None: move at the commanded rate instead."""
    yaw_lock: bool = False
    """The yaw target is in the earth frame (degrees from north)."""
    roi: tuple[float, float, float] | None = None
    """(lat, lon, alt AMSL) to point at."""
    t_ns: int | None = None


class GimbalDevice:
    """One vehicle's gimbal. The setters may be called from any thread (the MAVLink side); ``step`` runs in
    ``Autopilot.step``, under the lock."""

    def __init__(self, ap: Commander) -> None:
        self.ap = ap
        self.g = GimbalState()
        self.used = False
        """Set by the first setpoint: from then on the device moves with every step and is reported."""
        self.report: tuple[float, float] | None = None
        """(pitch, yaw relative to the heading) in degrees after the last step; None while never used."""

    # ------------------------------------------------------------------ setpoints (any thread)
    def set_angles(self, pitch_deg: float, yaw_deg: float, yaw_lock: bool = False) -> CommandResult:
        """Point at these angles (yaw from north with ``yaw_lock``, else from the heading)."""
        if not (math.isfinite(pitch_deg) and math.isfinite(yaw_deg)):
            return CommandResult.denied("gimbal: angles must be finite")
        with self.ap.lock:
            g = self._use()
            g.roi = None
            g.target_pitch_deg, g.target_yaw_deg = pitch_deg, yaw_deg
            g.yaw_lock = yaw_lock
        return CommandResult.accepted()

    def set_rates(self, pitch_rate_deg_s: float, yaw_rate_deg_s: float, yaw_lock: bool = False) -> CommandResult:
        if not (math.isfinite(pitch_rate_deg_s) and math.isfinite(yaw_rate_deg_s)):
            return CommandResult.denied("gimbal: rates must be finite")
        with self.ap.lock:
            g = self._use()
            g.roi = None
            g.target_pitch_deg = g.target_yaw_deg = None
            g.pitch_rate_deg_s, g.yaw_rate_deg_s = pitch_rate_deg_s, yaw_rate_deg_s
            g.yaw_lock = yaw_lock
        return CommandResult.accepted()

    def point_at(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> CommandResult:
        """Track a global position (a region of interest) until another setpoint."""
        if not all(math.isfinite(v) for v in (lat_deg, lon_deg, alt_amsl_m)) or abs(lat_deg) > 90 or abs(lon_deg) > 180:
            return CommandResult.denied("ROI: latitude, longitude and altitude must be valid")
        with self.ap.lock:
            self._use().roi = (lat_deg, lon_deg, alt_amsl_m)
        return CommandResult.accepted()

    def attitude(self) -> GimbalAttitude:
        with self.ap.lock:
            g = self.g
            return GimbalAttitude(g.pitch_deg, g.yaw_deg, g.pitch_rate_deg_s, g.yaw_rate_deg_s, g.yaw_lock)

    def _use(self) -> GimbalState:
        """Under the lock: the device moves from now (the last step's sim time) on."""
        g = self.g
        if not self.used:
            self.used = True
            t_ns = self.ap.core.t_ns
            g.t_ns = t_ns if t_ns >= 0 else None  # before the first step: it moves from the first step on
            self.report = (g.pitch_deg, g.yaw_deg)
        return g

    # ------------------------------------------------------------------ lockstep
    def step(self, t_ns: int, est: Estimator) -> None:
        """Move to sim time ``t_ns`` under the current setpoint (the heading and position are ``est``'s)."""
        g = self.g
        dt = 0.0 if g.t_ns is None else (t_ns - g.t_ns) / 1e9
        g.t_ns = t_ns
        if dt <= 0.0:
            return
        heading = math.degrees(est.yaw)
        tp, ty = g.target_pitch_deg, g.target_yaw_deg
        if g.roi is not None:
            tp, ty = _roi_angles(est, heading, g.roi)
        elif ty is not None and g.yaw_lock:
            ty = wrap180(ty - heading)
        if tp is None:
            g.pitch_deg = clamp(g.pitch_deg + g.pitch_rate_deg_s * dt, PITCH_MIN, PITCH_MAX)
        else:
            step = SLEW_DEG_S * dt
            new = g.pitch_deg + clamp(clamp(tp, PITCH_MIN, PITCH_MAX) - g.pitch_deg, -step, step)
            g.pitch_rate_deg_s = (new - g.pitch_deg) / dt
            g.pitch_deg = new
        if ty is None:
            g.yaw_deg = clamp(g.yaw_deg + g.yaw_rate_deg_s * dt, YAW_MIN, YAW_MAX)
        else:
            step = SLEW_DEG_S * dt
            new = g.yaw_deg + clamp(clamp(ty, YAW_MIN, YAW_MAX) - g.yaw_deg, -step, step)
            g.yaw_rate_deg_s = (new - g.yaw_deg) / dt
            g.yaw_deg = new
        self.report = (g.pitch_deg, g.yaw_deg)


def _roi_angles(est: Estimator, heading_deg: float, roi: tuple[float, float, float]) -> tuple[float, float]:
    lat0, lon0, alt0 = est.geo()
    lat, lon, alt = roi
    north = math.radians(lat - lat0) * 6_378_137.0
    east = math.radians(lon - lon0) * 6_378_137.0 * math.cos(math.radians(lat0))
    pitch = math.degrees(math.atan2(alt - alt0, math.hypot(north, east)))
    yaw = wrap180(math.degrees(math.atan2(east, north)) - heading_deg)
    return pitch, yaw
