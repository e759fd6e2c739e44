"""The autopilot's ``action`` service: arming, commanded mode changes and the commands that move the vehicle.

Each command is checked at once (under the autopilot's lock) and returns a ``CommandResult``; a refusal says
why. Modes entered by the commander itself (failsafes, end of takeoff) go through ``Autopilot.switch_mode``
without these checks.
"""

from __future__ import annotations

import math

from harness.autopilot.api import CommandResult, Failsafe, FlightMode, GeoPoint, LandedState, Severity
from harness.autopilot.follow import FollowTarget
from harness.autopilot.manual import ManualControl
from harness.autopilot.navigator import Orbit
from harness.autopilot.offboard import OffboardInput
from harness.autopilot.supervisor import Commander, arming_check
from harness.autopilot.validate import finite
from harness.core.geo import GeoRef


class Actions:
    """The commands of one vehicle."""

    def __init__(self, ap: Commander, offboard: OffboardInput, manual: ManualControl, follow: FollowTarget) -> None:
        self.ap = ap
        self.offboard = offboard
        self.manual = manual
        self.follow = follow

    # ------------------------------------------------------------------ arming
    def arm(self, force: bool = False) -> CommandResult:
        ap = self.ap
        with ap.lock:
            c = ap.core
            if c.armed:
                return CommandResult.accepted()
            if not force:
                why = arming_check(ap)
                if why:
                    ap.say(Severity.CRITICAL, f"Arming denied: {why}")
                    return CommandResult.denied(f"Arming denied: {why}")
            c.armed = True
            ap.supervisor.reset()
            ap.failsafe = Failsafe.NONE
            ap.set_home_here()
            c.landed_state = LandedState.ON_GROUND
            c.ground_pd = c.est.pd
            c.nav.enter(c.mode, True)
            ap.say(Severity.INFO, "Armed")
            return CommandResult.accepted()

    def disarm(self, force: bool = False) -> CommandResult:
        ap = self.ap
        with ap.lock:
            c = ap.core
            if not c.armed:
                return CommandResult.accepted()
            if c.landed_state != LandedState.ON_GROUND and not force:
                return CommandResult.denied("Disarming denied: in air (land first, or force to kill the motors)")
            ap.cut_motors("Disarmed" + (" (forced)" if force else ""))
            return CommandResult.accepted()

    # ------------------------------------------------------------------ modes
    def set_mode(self, mode: FlightMode) -> CommandResult:
        with self.ap.lock:
            return self._mode_locked(mode)

    def _mode_locked(self, mode: FlightMode) -> CommandResult:
        ap = self.ap
        c = ap.core
        refusal = self.manual.refuse(mode)
        if refusal is not None:
            return refusal
        if mode == FlightMode.FOLLOW_TARGET and (not c.armed or c.landed_state == LandedState.ON_GROUND):
            return CommandResult.denied("Follow target denied: not flying (take off first)")
        if mode == FlightMode.ORBIT:
            return CommandResult.denied("orbit needs a radius and speed: use the orbit command (DO_ORBIT)")
        if not c.est.att_valid:
            return CommandResult.rejected("estimator not ready")
        needs_pos = mode not in (FlightMode.LAND, FlightMode.ALTCTL, FlightMode.STABILIZED, FlightMode.MANUAL)
        if needs_pos and not c.est.pos_valid and c.armed:
            return CommandResult.denied(f"{mode.name} needs a position estimate")
        if mode == FlightMode.OFFBOARD and not self.offboard.age_s() <= ap.params["COM_OF_LOSS_T"]:
            return CommandResult.denied("Offboard denied: no setpoint received recently (stream setpoints first)")
        if mode == FlightMode.MISSION and not c.nav.items:
            return CommandResult.denied("Mission denied: no mission uploaded")
        if mode == FlightMode.RTL and ap.home_ned is None:
            return CommandResult.denied("Return denied: no home position")
        if mode == FlightMode.OFFBOARD:
            self.offboard.apply()
        if mode == FlightMode.FOLLOW_TARGET:
            self.follow.enter()
        if ap.failsafe and mode != c.mode:
            ap.failsafe = Failsafe.NONE
        ap.switch_mode(mode)
        return CommandResult.accepted()

    def takeoff(self, alt_m: float | None = None) -> CommandResult:
        ap = self.ap
        with ap.lock:
            c = ap.core
            alt = ap.params["MIS_TAKEOFF_ALT"] if alt_m is None or math.isnan(alt_m) else alt_m
            if not math.isfinite(alt) or not 0.5 <= alt <= 1000.0:
                return CommandResult.denied(f"Takeoff denied: altitude {alt_m} m outside [0.5, 1000] m")
            if not c.est.pos_valid:
                return CommandResult.rejected("Takeoff denied: no position estimate")
            c.nav.set_takeoff_alt(alt)
            return self._mode_locked(FlightMode.TAKEOFF)

    def land(self) -> CommandResult:
        return self.set_mode(FlightMode.LAND)

    def return_to_launch(self) -> CommandResult:
        return self.set_mode(FlightMode.RTL)

    def hold(self) -> CommandResult:
        return self.set_mode(FlightMode.HOLD)

    # ------------------------------------------------------------------ guided
    def _flying(self) -> str:
        c = self.ap.core
        if not c.armed or c.landed_state == LandedState.ON_GROUND:
            return "not flying (arm and take off first)"
        if c.est.ref is None:
            return "no global position"
        return ""

    def _point_or_here(
        self, lat_deg: float | None, lon_deg: float | None, alt_amsl_m: float | None
    ) -> tuple[GeoRef, float, float, float]:
        """The local frame and a point whose missing coordinates (None, or NaN as MAVLink sends them) are where
        the vehicle is (under the lock, once ``_flying`` passed: there is a frame)."""
        e = self.ap.core.est
        ref = e.ref
        assert ref is not None
        here = e.geo()
        given = (lat_deg, lon_deg, alt_amsl_m)
        lat, lon, alt = (h if v is None or math.isnan(v) else v for v, h in zip(given, here, strict=True))
        return ref, lat, lon, alt

    def reposition(
        self, lat_deg: float | None, lon_deg: float | None, alt_amsl_m: float | None, yaw_rad: float | None = None
    ) -> CommandResult:
        ap = self.ap
        with ap.lock:
            why = self._flying()
            if why:
                return CommandResult.rejected(f"Reposition rejected: {why}")
            c = ap.core
            ref, lat, lon, alt = self._point_or_here(lat_deg, lon_deg, alt_amsl_m)
            if not finite([lat, lon, alt]) or abs(lat) > 90 or abs(lon) > 180:
                return CommandResult.denied("Reposition denied: invalid coordinates")
            target = ref.to_ned(lat, lon, alt)
            yaw = None if yaw_rad is None or not math.isfinite(yaw_rad) else yaw_rad
            c.mode = FlightMode.HOLD
            c.nav.goto(target, yaw)
            ap.state_changed()
            return CommandResult.accepted()

    def orbit(
        self,
        radius_m: float,
        velocity_m_s: float,
        center_lat_deg: float | None = None,
        center_lon_deg: float | None = None,
        alt_amsl_m: float | None = None,
    ) -> CommandResult:
        ap = self.ap
        with ap.lock:
            why = self._flying()
            if why:
                return CommandResult.rejected(f"Orbit rejected: {why}")
            if not finite([radius_m, velocity_m_s]) or not 1.0 <= abs(radius_m) <= 10_000.0:
                return CommandResult.denied(f"Orbit denied: radius {radius_m} m outside [1, 10000] m")
            if abs(velocity_m_s) > ap.params["MPC_XY_VEL_MAX"]:
                return CommandResult.denied(f"Orbit denied: speed {velocity_m_s} m/s above MPC_XY_VEL_MAX")
            c = ap.core
            ref, lat, lon, alt = self._point_or_here(center_lat_deg, center_lon_deg, alt_amsl_m)
            n, east, d = ref.to_ned(lat, lon, alt)
            c.mode = FlightMode.ORBIT
            c.nav.start_orbit(Orbit(n, east, d, radius_m, velocity_m_s))
            ap.state_changed()
            return CommandResult.accepted()

    def set_yaw(self, yaw_rad: float | None) -> CommandResult:
        """Turn the nose to ``yaw_rad`` (rad from north) at the auto yaw rate and keep it there while the
        position target or velocity changes (ArduCopter's CONDITION_YAW and region of interest); None
        lets the active mode choose again. Until the next mode change."""
        if yaw_rad is not None and not math.isfinite(yaw_rad):
            return CommandResult.denied(f"yaw {yaw_rad} is not finite")
        ap = self.ap
        with ap.lock:
            why = self._flying()
            if why:
                return CommandResult.rejected(f"Yaw rejected: {why}")
            ap.core.nav.point_nose(None if yaw_rad is None else math.remainder(yaw_rad, math.tau))
            return CommandResult.accepted()

    def reboot(self) -> CommandResult:
        """Restart the flight stack in place, as a SITL reboot does (on the ground, disarmed): a new flight core
        (estimator, controllers, modes, sticks) on the same parameters, the stored missions and fence kept, home
        and failsafes forgotten. Sim time goes on; physics never stopped."""
        ap = self.ap
        with ap.lock:
            if ap.core.armed:
                return CommandResult.failed("Reboot refused: the vehicle is armed")
            ap.restart()
            return CommandResult.accepted()

    def change_speed(self, speed_m_s: float) -> CommandResult:
        ap = self.ap
        if not math.isfinite(speed_m_s) or not 0.0 < speed_m_s <= ap.params["MPC_XY_VEL_MAX"]:
            return CommandResult.denied(f"speed {speed_m_s} m/s outside (0, MPC_XY_VEL_MAX]")
        with ap.lock:
            ap.core.nav.set_cruise(speed_m_s)
            ap.state_changed()
            return CommandResult.accepted()

    def set_home(self, point: GeoPoint | None = None) -> CommandResult:
        ap = self.ap
        with ap.lock:
            e = ap.core.est
            if e.ref is None:
                return CommandResult.rejected("no global position yet")
            if point is None:
                ap.set_home_here()
            else:
                if not finite([point.lat_deg, point.lon_deg, point.alt_amsl_m]) or abs(point.lat_deg) > 90:
                    return CommandResult.denied("invalid home position")
                ap.home = point
                ap.home_ned = e.ref.to_ned(point.lat_deg, point.lon_deg, point.alt_amsl_m)
                ap.core.nav.set_home(ap.home_ned)
            ap.state_changed()
            return CommandResult.accepted()
