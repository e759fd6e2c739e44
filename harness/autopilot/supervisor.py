"""The commander's periodic checks: arming checks, auto-disarm, mode completion and failsafes.

Functions over an ``Autopilot``, called under its lock (``supervise`` at ``AutopilotConfig.supervise_hz``
of sim time, ``arming_check`` on every arm request and health report).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from harness.autopilot.api import FlightMode, LandedState, Severity

if TYPE_CHECKING:
    from harness.autopilot.autopilot import Autopilot


def arming_check(ap: Autopilot) -> str:
    """'' when the vehicle may arm, else the first reason it may not."""
    c = ap.core
    e = c.est
    p = ap.params
    t = max(c.t_ns, 0)
    if c.t_ns < 0 or t - e.last_imu_ns > 500_000_000:
        return "no IMU data"
    if not e.att_valid:
        return "attitude estimate not initialised"
    if not p["COM_ARM_WO_GPS"]:
        g = e.gps
        if g is None or g.fix_type < 3:
            return f"no 3D GPS fix (fix type {0 if g is None else g.fix_type})"
        if not e.gps_fix_ok():
            return f"GPS not good enough ({g.satellites} satellites, eph {g.eph_m:.1f} m)"
        if not e.pos_valid:
            return "position estimate not converged"
    if c.battery.remaining < p["BAT_LOW_THR"]:
        return f"battery low ({c.battery.remaining:.0%})"
    refusal = ap.manual.refuse(c.mode)
    if refusal is not None:
        return refusal.reason
    if c.mode == FlightMode.OFFBOARD and not ap._offboard_fresh():
        return "offboard mode without a recent setpoint"
    if c.mode == FlightMode.MISSION and not c.nav.items:
        return "mission mode without a mission"
    return ""


def supervise(ap: Autopilot) -> None:
    """Auto-disarm, end of takeoff and mission, battery, offboard-loss and geofence failsafes."""
    c = ap.core
    p = ap.params
    t = c.t_ns
    nav = c.nav
    in_air = c.armed and c.landed_state != LandedState.ON_GROUND
    # auto-disarm: after touchdown, and when armed but never taken off
    if c.armed and c.landed_state == LandedState.ON_GROUND:
        if ap._landed_since_ns is None:
            ap._landed_since_ns = t
        waited = (t - ap._landed_since_ns) * 1e-9
        limit = p["COM_DISARM_LAND"] if ap._was_airborne else p["COM_DISARM_PRFLT"]
        if limit > 0 and waited > limit and not nav.wants_climb and not ap._offboard_climbing():
            ap._disarm("Disarmed after landing" if ap._was_airborne else "Disarmed: no takeoff")
            return
    else:
        ap._landed_since_ns = None
        if in_air:
            ap._was_airborne = True
    if c.mode == FlightMode.TAKEOFF and in_air and nav.takeoff_reached():
        ap._say(Severity.INFO, "Takeoff complete")
        ap._set_mode(FlightMode.HOLD)
    if c.mode == FlightMode.MISSION and nav.mission_done:
        nav.mission_done = False
        ap._say(Severity.INFO, "Mission finished")
        if in_air and not nav.landing:
            ap._set_mode(FlightMode.HOLD)
    if not in_air:
        return
    rem = c.battery.remaining
    if rem < p["BAT_CRIT_THR"] and ap.failsafe != "battery_critical":
        ap.failsafe = "battery_critical"
        ap._say(Severity.CRITICAL, f"Battery critical ({rem:.0%}): landing")
        ap._set_mode(FlightMode.LAND)
    elif rem < p["BAT_LOW_THR"] and ap.failsafe not in ("battery", "battery_critical"):
        ap.failsafe = "battery"
        act = int(p["COM_LOW_BAT_ACT"])
        ap._say(Severity.WARNING, f"Battery low ({rem:.0%})" + (": returning" if act == 3 else ""))
        if act == 3 and ap.home_ned is not None:
            ap._set_mode(FlightMode.RTL)
        elif act in (2, 3):
            ap._set_mode(FlightMode.LAND)
    if c.mode == FlightMode.OFFBOARD:
        lost_s = (ap.wall.now_ns() - ap._offboard_wall_ns) * 1e-9
        if lost_s > p["COM_OF_LOSS_T"]:
            ap.failsafe = "offboard_loss"
            act = int(p["COM_OBL_RC_ACT"])
            target = {3: FlightMode.RTL, 4: FlightMode.LAND}.get(act, FlightMode.HOLD)
            ap._say(Severity.WARNING, f"Offboard setpoints lost for {lost_s:.1f} s: {target.name}")
            ap._set_mode(target)
    if ap.home_ned is not None:
        est = c.est
        breach = c.fence.breach((est.pn, est.pe, est.pd), ap.home_ned, ap._to_local)
        if breach and not ap._fence_breached:
            ap._fence_breached = True
            act = int(p["GF_ACTION"])
            ap._say(Severity.CRITICAL, f"Geofence breached: {breach}")
            if act >= 2 and c.mode not in (FlightMode.RTL, FlightMode.LAND):
                ap.failsafe = "geofence"
                ap._set_mode({2: FlightMode.HOLD, 3: FlightMode.RTL}.get(act, FlightMode.LAND))
        elif not breach:
            ap._fence_breached = False
