"""PX4's follow-target mode (AUTO.FOLLOW_TARGET) fed by MAVLink FOLLOW_TARGET.

As PX4's ``FlightTaskAutoFollowTarget``: the target's position is smoothed (``FLW_TGT_RS``: 0 follows every
sample at once, towards 1 smooths more); the vehicle keeps ``FLW_TGT_DST`` metres from it horizontally at
``FLW_TGT_FA`` degrees from the target's course (0 in front, 180 behind, clockwise positive; while the
target stands still the last course is kept, and before it ever moved the side the vehicle is on), at
``FLW_TGT_HT`` above home (``FLW_TGT_ALT_M`` 0, and 1: we have no terrain, so as 0) or above the target's
GPS altitude (2), never lower than 1 m above home (PX4's minimum safety altitude); it flies there at up to
``FLW_TGT_MAX_VEL`` and points its nose at the target. Without a target sample for 2.5 s of sim time (or
before the first) it holds where it is.
"""

from __future__ import annotations

import math

from harness.autopilot.api import CommandResult
from harness.autopilot.supervisor import Commander

TARGET_TIMEOUT_NS = 2_500_000_000
MIN_SAFETY_ALT_M = 1.0
_MOVING_M_S = 0.5


class FollowTarget:
    """The follow-target state of one vehicle: the autopilot's ``follow_me`` service. ``set_target`` takes the
    autopilot's lock; the rest is called by the autopilot under it."""

    def __init__(self, ap: Commander) -> None:
        self.ap = ap
        self.reset()

    def reset(self) -> None:
        """As at boot: no target (a reboot of the flight stack)."""
        self.target: tuple[float, float, float] | None = None
        """Smoothed target position (local NED, m)."""
        self.target_vel: tuple[float, float] = (0.0, 0.0)
        self.last_ns: int | None = None
        self.course: float | None = None
        self._hold: tuple[float, float, float] | None = None

    def set_target(
        self, lat_deg: float, lon_deg: float, alt_amsl_m: float, vel_ned_m_s: tuple[float, float, float]
    ) -> CommandResult:
        """One FOLLOW_TARGET position of the target."""
        with self.ap.lock:
            return self._set_target(lat_deg, lon_deg, alt_amsl_m, vel_ned_m_s)

    def _set_target(
        self, lat_deg: float, lon_deg: float, alt_amsl_m: float, vel_ned_m_s: tuple[float, float, float]
    ) -> CommandResult:
        ref = self.ap.core.est.ref
        if ref is None:
            return CommandResult.rejected("follow target: no global position yet")
        if not all(math.isfinite(v) for v in (lat_deg, lon_deg, alt_amsl_m)) or abs(lat_deg) > 90:
            return CommandResult.denied("follow target: invalid position")
        n, e, d = ref.to_ned(lat_deg, lon_deg, alt_amsl_m)
        t = max(self.ap.core.t_ns, 0)
        prev, prev_t = self.target, self.last_ns
        if prev is None or prev_t is None:
            self.target = (n, e, d)
        else:
            k = 1.0 - self.ap.params["FLW_TGT_RS"]
            self.target = (prev[0] + k * (n - prev[0]), prev[1] + k * (e - prev[1]), prev[2] + k * (d - prev[2]))
        vn, ve = vel_ned_m_s[0], vel_ned_m_s[1]
        if not (math.isfinite(vn) and math.isfinite(ve)):
            dt = (t - prev_t) * 1e-9 if prev_t is not None else 0.0
            vn, ve = ((n - prev[0]) / dt, (e - prev[1]) / dt) if prev is not None and dt > 0 else (0.0, 0.0)
        self.target_vel = (vn, ve)
        if math.hypot(vn, ve) > _MOVING_M_S:
            self.course = math.atan2(ve, vn)
        self.last_ns = t
        return CommandResult.accepted()

    def enter(self) -> None:
        e = self.ap.core.est
        self._hold = (e.pn, e.pe, e.pd)

    def update(self, dt: float) -> None:
        """The navigator's setpoint in FOLLOW_TARGET (the navigator calls it every update)."""
        ap = self.ap
        c = ap.core
        e = c.est
        nav = c.nav
        p = ap.params
        tgt = self.target
        if tgt is None or self.last_ns is None or c.t_ns - self.last_ns > TARGET_TIMEOUT_NS:
            if self._hold is None:
                self.enter()
            assert self._hold is not None
            nav.track(self._hold, dt)
            return
        self._hold = None
        fa = math.radians(p["FLW_TGT_FA"])
        if self.course is None:  # the target never moved: stay on the side the vehicle is on
            self.course = math.atan2(e.pe - tgt[1], e.pn - tgt[0]) - fa
        bearing = self.course + fa
        dist = p["FLW_TGT_DST"]
        n, east = tgt[0] + dist * math.cos(bearing), tgt[1] + dist * math.sin(bearing)
        home_d = ap.home_ned[2] if ap.home_ned is not None else 0.0
        base = tgt[2] if int(p["FLW_TGT_ALT_M"]) == 2 else home_d
        d = min(base - p["FLW_TGT_HT"], home_d - MIN_SAFETY_ALT_M)
        if math.hypot(tgt[0] - e.pn, tgt[1] - e.pe) > 1.0:
            nav.point_to(math.atan2(tgt[1] - e.pe, tgt[0] - e.pn))
        nav.track((n, east, d), dt, v_xy=max(p["FLW_TGT_MAX_VEL"], 0.1))
