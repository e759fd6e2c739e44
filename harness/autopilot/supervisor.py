"""The commander's periodic checks: arming checks, auto-disarm, mode completion and failsafes.

:class:`Supervisor` holds the checks' own state (since when the vehicle is on the ground, whether it has
flown, whether the fence is breached) and acts on its autopilot only through :class:`Supervised`, called
under the autopilot's lock (``Supervisor.check`` at ``AutopilotConfig.supervise_hz`` of sim time,
``arming_check`` on every arm request and health report).
"""

from __future__ import annotations

import threading
from typing import Protocol

from harness.autopilot.api import Failsafe, FlightMode, GeoPoint, LandedState, Severity
from harness.autopilot.flight import FlightCore
from harness.autopilot.params import Params
from harness.core.clock import Clock
from harness.core.geo import Vec3


class OffboardStatus(Protocol):
    """What the supervisor reads of the offboard service."""

    def age_s(self) -> float:
        """Sim seconds since the last offboard setpoint."""
        ...

    def climbing(self) -> bool:
        """OFFBOARD asks to leave the ground (the auto-disarm waits)."""
        ...

    def flies_attitude(self) -> bool:
        """Whether OFFBOARD flies attitude targets (the last offboard input was SET_ATTITUDE_TARGET)."""
        ...


class StickStatus(Protocol):
    """What the supervisor reads of manual control."""

    def refusal(self, mode: FlightMode) -> str:
        """Why ``mode`` may not be flown without its manual control input ('' when it may)."""
        ...

    def fresh(self) -> bool:
        """A stick input within ``COM_RC_LOSS_T``."""
        ...


class Supervised(Protocol):
    """What the supervisor and the add-on modes read of, and may do to, their autopilot
    (``harness.autopilot.autopilot.Autopilot``): the flight core and the commander's state."""

    core: FlightCore
    params: Params
    home_ned: Vec3 | None
    failsafe: Failsafe

    @property
    def offboard(self) -> OffboardStatus: ...

    @property
    def manual_control(self) -> StickStatus: ...

    def say(self, severity: Severity, text: str) -> None:
        """Queue a status text."""
        ...

    def switch_mode(self, mode: FlightMode) -> None:
        """Enter ``mode`` without the checks of a commanded mode change."""
        ...

    def cut_motors(self, why: str) -> None:
        """Disarm now and say why."""
        ...

    def state_changed(self) -> None:
        """Drop the cached state snapshot."""
        ...

    def to_local(self, lat_deg: float, lon_deg: float) -> tuple[float, float]: ...


class Commander(Supervised, Protocol):
    """What the services (``action``, ``mission``, ``offboard``, ...) act through: the supervised state,
    the lock that serialises commands with ``step()``, home and the wall clock."""

    vehicle: int
    lock: threading.Lock
    wall: Clock
    home: GeoPoint | None
    supervisor: Supervisor

    def set_home_here(self) -> None:
        """Home where the vehicle is now (on arming, and DO_SET_HOME with 'current')."""
        ...

    def restart(self) -> None:
        """A new flight stack on the same parameters, plans and sim time (a reboot; disarmed, under the lock)."""
        ...


def arming_check(ap: Supervised) -> str:
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
    refusal = ap.manual_control.refusal(c.mode)
    if refusal:
        return refusal
    if c.mode == FlightMode.OFFBOARD and not ap.offboard.age_s() <= p["COM_OF_LOSS_T"]:
        return "offboard mode without a recent setpoint"
    if c.mode == FlightMode.MISSION and not c.nav.items:
        return "mission mode without a mission"
    return ""


class Supervisor:
    """Auto-disarm, end of takeoff and mission, battery, offboard-loss and geofence failsafes."""

    __slots__ = ("fence_breached", "landed_since_ns", "was_airborne")

    def __init__(self) -> None:
        self.landed_since_ns: int | None = None
        self.was_airborne = False
        self.fence_breached = False

    def reset(self) -> None:
        """Forget the flight: on arming and disarming."""
        self.landed_since_ns = None
        self.was_airborne = False

    def check(self, ap: Supervised) -> None:
        c = ap.core
        p = ap.params
        t = c.t_ns
        nav = c.nav
        in_air = c.armed and c.landed_state != LandedState.ON_GROUND
        # auto-disarm: after touchdown, and when armed but never taken off
        if c.armed and c.landed_state == LandedState.ON_GROUND:
            if self.landed_since_ns is None:
                self.landed_since_ns = t
            waited = (t - self.landed_since_ns) * 1e-9
            limit = p["COM_DISARM_LAND"] if self.was_airborne else p["COM_DISARM_PRFLT"]
            if limit > 0 and waited > limit and not nav.wants_climb and not ap.offboard.climbing():
                ap.cut_motors("Disarmed after landing" if self.was_airborne else "Disarmed: no takeoff")
                return
        else:
            self.landed_since_ns = None
            if in_air:
                self.was_airborne = True
        if c.mode == FlightMode.TAKEOFF and in_air and nav.takeoff_reached():
            ap.say(Severity.INFO, "Takeoff complete")
            ap.switch_mode(FlightMode.HOLD)
        if c.mode == FlightMode.MISSION and nav.take_mission_done():
            ap.say(Severity.INFO, "Mission finished")
            if in_air and not nav.landing:
                ap.switch_mode(FlightMode.HOLD)
        if not in_air:
            return
        self._battery(ap)
        if c.mode == FlightMode.OFFBOARD:
            lost_s = ap.offboard.age_s()
            if lost_s > p["COM_OF_LOSS_T"]:
                ap.failsafe = Failsafe.OFFBOARD_LOSS
                act = int(p["COM_OBL_RC_ACT"])
                target = {3: FlightMode.RTL, 4: FlightMode.LAND}.get(act, FlightMode.HOLD)
                ap.say(Severity.WARNING, f"Offboard setpoints lost for {lost_s:.1f} s: {target.name}")
                ap.switch_mode(target)
        self._fence(ap)

    @staticmethod
    def _battery(ap: Supervised) -> None:
        c = ap.core
        p = ap.params
        rem = c.battery.remaining
        if rem < p["BAT_CRIT_THR"] and ap.failsafe != Failsafe.BATTERY_CRITICAL:
            ap.failsafe = Failsafe.BATTERY_CRITICAL
            ap.say(Severity.CRITICAL, f"Battery critical ({rem:.0%}): landing")
            ap.switch_mode(FlightMode.LAND)
        elif rem < p["BAT_LOW_THR"] and ap.failsafe not in (Failsafe.BATTERY, Failsafe.BATTERY_CRITICAL):
            ap.failsafe = Failsafe.BATTERY
            act = int(p["COM_LOW_BAT_ACT"])
            ap.say(Severity.WARNING, f"Battery low ({rem:.0%})" + (": returning" if act == 3 else ""))
            if act == 3 and ap.home_ned is not None:
                ap.switch_mode(FlightMode.RTL)
            elif act in (2, 3):
                ap.switch_mode(FlightMode.LAND)

    def _fence(self, ap: Supervised) -> None:
        if ap.home_ned is None:
            return
        c = ap.core
        est = c.est
        breach = c.fence.breach((est.pn, est.pe, est.pd), ap.home_ned, ap.to_local)
        if breach and not self.fence_breached:
            self.fence_breached = True
            act = int(ap.params["GF_ACTION"])
            ap.say(Severity.CRITICAL, f"Geofence breached: {breach}")
            if act >= 2 and c.mode not in (FlightMode.RTL, FlightMode.LAND):
                ap.failsafe = Failsafe.GEOFENCE
                ap.switch_mode({2: FlightMode.HOLD, 3: FlightMode.RTL}.get(act, FlightMode.LAND))
        elif not breach:
            self.fence_breached = False
