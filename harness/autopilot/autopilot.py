"""The autopilot: the thread-safe command API (``AutopilotApi``), arming checks and failsafes around the
flight core.

``step(frame)`` runs once per tick in lockstep and returns the four motor commands; every other method may
be called from any thread (the MAVLink side calls them on the wall clock). One lock serialises them:
a command changes the state between two steps and its effect shows in the next step.
"""

from __future__ import annotations

import enum
import math
import threading
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from harness.autopilot.api import (
    AttitudeTarget,
    CommandResult,
    Failsafe,
    FlightMode,
    GeoPoint,
    LandedState,
    MissionItem,
    MissionKind,
    MissionReached,
    OffboardSetpoint,
    Severity,
    StatusText,
    TickStatus,
    VehicleState,
)
from harness.autopilot.failures import FailureInjector
from harness.autopilot.flight import FlightCore
from harness.autopilot.flightlog import FlightLog
from harness.autopilot.follow import FollowTarget
from harness.autopilot.manual import ManualControl
from harness.autopilot.navigator import MissionPhase, Orbit
from harness.autopilot.params import Params
from harness.autopilot.snapshot import build_state
from harness.autopilot.supervisor import Supervisor, arming_check
from harness.autopilot.validate import check_mission, finite
from harness.core.clock import WALL, Clock
from harness.core.errors import ScenarioError
from harness.core.geo import GeoRef
from harness.fdm.frame import SensorFrame

_MODE_NUMBERS: dict[FlightMode, tuple[int, int]] = {m: (int(m.value[0]), int(m.value[1])) for m in FlightMode}
"""PX4 (main, sub) mode numbers of each flight mode, for END-TICK-AC (``FlightMode.value`` is an enum
property: computed once here instead of twice per tick)."""


class OffboardKind(enum.Enum):
    """Which offboard input came last: it is the one OFFBOARD mode flies."""

    NONE = enum.auto()
    SETPOINT = enum.auto()
    """Position / velocity / acceleration (SET_POSITION_TARGET_*)."""
    ATTITUDE = enum.auto()
    """Attitude and thrust (SET_ATTITUDE_TARGET)."""


@dataclass(frozen=True)
class AutopilotConfig:
    vehicle: int = 0
    use_ground_truth: bool = False
    """Debugging only: take position, velocity and attitude from the frame's ground truth."""
    origin: tuple[float, float, float] | None = None
    """(lat_deg, lon_deg, alt_amsl_m) of the local frame; default: where the first good GPS fix was taken."""
    params: Mapping[str, float] = field(default_factory=dict)
    supervise_hz: float = 10.0
    """Rate of the failsafe and auto-disarm checks (sim time)."""


class Autopilot:
    """One vehicle's autopilot. See ``harness.autopilot.api.AutopilotApi`` for the method contracts."""

    def __init__(
        self, config: AutopilotConfig | None = None, params: Params | None = None, wall_clock: Clock | None = None
    ) -> None:
        cfg = config or AutopilotConfig()
        self.config = cfg
        self.vehicle = cfg.vehicle
        self.params = params if params is not None else Params(overrides=cfg.params)
        self.wall = wall_clock if wall_clock is not None else WALL
        origin = GeoRef(*cfg.origin) if cfg.origin is not None else None
        self.core = FlightCore(self.params, cfg.use_ground_truth, origin)
        self._lock = threading.Lock()
        self._texts: deque[StatusText] = deque(maxlen=200)
        self._reached: deque[MissionReached] = deque(maxlen=1000)
        self._rally: tuple[MissionItem, ...] = ()
        self.home: GeoPoint | None = None
        self.home_ned: tuple[float, float, float] | None = None
        self.failsafe = Failsafe.NONE
        self._offboard_t_ns = -(10**18)
        """Sim time of the last offboard setpoint: PX4 in lockstep judges COM_OF_LOSS_T on its own (sim) clock."""
        if not cfg.supervise_hz > 0:
            raise ScenarioError(f"autopilot {cfg.vehicle}: supervise_hz must be > 0, got {cfg.supervise_hz}")
        self._super_period_ns = round(1e9 / cfg.supervise_hz)
        self._next_super_ns = 0
        self._armed_ns = 0
        self.supervisor = Supervisor()
        self._offboard_kind = OffboardKind.NONE
        self._offboard_sp: OffboardSetpoint | None = None
        self._offboard_att: AttitudeTarget | None = None
        self._cache: VehicleState | None = None
        self._bell: Callable[[], None] | None = None
        self._bell_armed = False
        self._ring_at_ns = 0
        self._rung_status: TickStatus | None = None
        self._numbered_mode: FlightMode | None = None
        self._mode_numbers = (0, 0)
        self.failures = FailureInjector(self)
        self.manual = ManualControl(self)
        self.follow = FollowTarget(self)
        self.flight_log: FlightLog | None = None
        """The vehicle's ULog (``harness.autopilot.flightlog``), when the run writes one."""
        self._hook_modes()

    def _hook_modes(self) -> None:
        hooks = self.core.nav.mode_hooks
        hooks[FlightMode.POSCTL] = hooks[FlightMode.ALTCTL] = self.manual._setpoint
        hooks[FlightMode.FOLLOW_TARGET] = self.follow.update

    def reboot(self) -> CommandResult:
        """Restart the flight stack in place, as a SITL reboot does (on the ground, disarmed): a new flight core
        (estimator, controllers, modes, sticks) on the same parameters, the stored missions and fence kept, home
        and failsafes forgotten. Sim time goes on; physics never stopped."""
        with self._lock:
            old = self.core
            if old.armed:
                return CommandResult.failed("Reboot refused: the vehicle is armed")
            cfg = self.config
            self.core = FlightCore(self.params, cfg.use_ground_truth, GeoRef(*cfg.origin) if cfg.origin else None)
            self.core.nav.items = list(old.nav.items)
            self.core.fence.set_items(old.fence.items)
            self.core.t_ns = old.t_ns
            self.home = self.home_ned = None
            self.failsafe = Failsafe.NONE
            self.supervisor = Supervisor()
            self._offboard_kind, self._offboard_sp, self._offboard_att = OffboardKind.NONE, None, None
            self.manual = ManualControl(self)
            self.follow = FollowTarget(self)
            self._hook_modes()
            self._cache = None
            return CommandResult.accepted()

    # ------------------------------------------------------------------ lockstep
    def step(self, frame: SensorFrame) -> tuple[float, float, float, float]:
        with self._lock:
            c = self.core
            self.manual.pre_step()
            motors = c.motors = self.failures.motors(c.step(self.failures.sensors(frame)))
            if self.flight_log is not None:
                self.flight_log.record(self)
            if c.t_ns >= self._next_super_ns:
                self._next_super_ns = c.t_ns + self._super_period_ns
                self.supervisor.check(self)
                self.failures.supervise()
                self.manual.supervise()
            nav = c.nav
            if nav.new_reached:
                for s in nav.new_reached:
                    self._reached.append(MissionReached(frame.t_ns, s))
                    self.say(Severity.INFO, f"Mission item {s} reached")
                nav.new_reached.clear()
            if c.texts:
                for sev, text in c.texts:
                    self.say(Severity(sev), text)
                c.texts.clear()
            self._cache = None
            ring = False
            if self._bell_armed:
                status = self.tick_status()
                if c.t_ns >= self._ring_at_ns or self._texts or self._reached or status != self._rung_status:
                    self._bell_armed = False
                    self._rung_status = status
                    ring = True
        if ring:  # outside the lock: the MAVLink side reads the state through the locked API
            assert self._bell is not None
            self._bell()
        return motors

    # ------------------------------------------------------------------ telemetry bell
    def attach_bell(self, bell: Callable[[], None]) -> None:
        """Let the stepping thread call ``bell()`` (after the step, outside the lock) when the MAVLink side
        has something to do: the MAVLink server then sends its sim-rate telemetry in lockstep, at the tick
        it falls due, whatever the speed of the simulation.

        It rings once sim time reaches the time given to :meth:`ring_at` (the next sim-rate telemetry
        stream), or as soon as the flight mode, arming or landed state changes, a status text is said or a
        mission item is reached; then it stays silent until :meth:`ring_at` arms it again.
        """
        self._bell = bell
        self.ring_at(0)

    def ring_at(self, t_ns: int) -> None:
        """Arm the bell for sim time ``t_ns`` (any thread; the MAVLink server calls it after each service)."""
        if self._bell is not None:
            self._ring_at_ns = t_ns
            self._bell_armed = True

    # ------------------------------------------------------------------ for the supervisor (under the lock)
    def say(self, severity: Severity, text: str) -> None:
        self._texts.append(StatusText(max(self.core.t_ns, 0), severity, text))
        if self.flight_log is not None:
            self.flight_log.text(self.core.t_ns, severity, text)

    def switch_mode(self, mode: FlightMode) -> None:
        c = self.core
        if c.mode != mode or mode in (FlightMode.TAKEOFF, FlightMode.HOLD, FlightMode.RTL):
            c.mode = mode
            c.nav.enter(mode, c.landed_state == LandedState.ON_GROUND)
        self._cache = None

    def offboard_climbing(self) -> bool:
        c = self.core
        return c.mode == FlightMode.OFFBOARD and c._climb_requested(c.nav.sp)

    def state_changed(self) -> None:
        self._cache = None

    def flies_attitude(self) -> bool:
        """Whether OFFBOARD flies attitude targets (the last offboard input was SET_ATTITUDE_TARGET)."""
        return self._offboard_kind == OffboardKind.ATTITUDE

    def manual_refusal(self, mode: FlightMode) -> str:
        refusal = self.manual.refuse(mode)
        return "" if refusal is None else refusal.reason

    def to_local(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        ref = self.core.est.ref
        if ref is None:
            return (math.nan, math.nan)
        n, e, _ = ref.to_ned(lat_deg, lon_deg, ref.alt_m)
        return (n, e)

    def offboard_age_s(self) -> float:
        """Sim seconds since the last offboard setpoint (a mission's setpoints, and MAVSDK's resends, follow sim
        time: on the wall clock a loaded machine's gap between two phases read as a lost setpoint stream)."""
        return (self.core.t_ns - self._offboard_t_ns) * 1e-9

    def cut_motors(self, why: str) -> None:
        c = self.core
        c.armed = False
        c.motors = (0.0, 0.0, 0.0, 0.0)
        self.supervisor.reset()
        self.say(Severity.INFO, why)
        self._cache = None

    # ------------------------------------------------------------------ state
    def tick_status(self) -> TickStatus:
        """Armed, landed state and PX4 mode, for END-TICK-AC (packed there by ``protocol.pack_status``)."""
        c = self.core
        mode = c.mode
        if mode is not self._numbered_mode:  # (an enum's hash is a Python call: looked up on a change only)
            self._numbered_mode = mode
            self._mode_numbers = _MODE_NUMBERS[mode]
        main, sub = self._mode_numbers
        return (c.armed, int(c.landed_state) if c.armed else 1, main, sub)

    def state(self) -> VehicleState:
        with self._lock:
            if self._cache is None:
                preflight_ok = self.arming_check() == ""
                self._cache = build_state(
                    self.core, self.vehicle, self.home, self.home_ned, self.failsafe, preflight_ok, self.failures
                )
            return self._cache

    def pop_status_texts(self) -> list[StatusText]:
        with self._lock:
            out = list(self._texts)
            self._texts.clear()
            return out

    def pop_mission_reached(self) -> list[MissionReached]:
        with self._lock:
            out = list(self._reached)
            self._reached.clear()
            return out

    # ------------------------------------------------------------------ arming
    def arming_check(self) -> str:
        """'' when the vehicle may arm, else the first reason it may not."""
        return arming_check(self)

    def arm(self, force: bool = False) -> CommandResult:
        with self._lock:
            c = self.core
            if c.armed:
                return CommandResult.accepted()
            if not force:
                why = self.arming_check()
                if why:
                    self.say(Severity.CRITICAL, f"Arming denied: {why}")
                    return CommandResult.denied(f"Arming denied: {why}")
            c.armed = True
            self._armed_ns = c.t_ns
            self.supervisor.reset()
            self.failsafe = Failsafe.NONE
            self._set_home_here()
            c.landed_state = LandedState.ON_GROUND
            c.ground_pd = c.est.pd
            c.nav.enter(c.mode, True)
            self.say(Severity.INFO, "Armed")
            return CommandResult.accepted()

    def disarm(self, force: bool = False) -> CommandResult:
        with self._lock:
            c = self.core
            if not c.armed:
                return CommandResult.accepted()
            if c.landed_state != LandedState.ON_GROUND and not force:
                return CommandResult.denied("Disarming denied: in air (land first, or force to kill the motors)")
            self.cut_motors("Disarmed" + (" (forced)" if force else ""))
            return CommandResult.accepted()

    def _set_home_here(self) -> None:
        e = self.core.est
        self.home_ned = (e.pn, e.pe, e.pd)
        lat, lon, alt = e.geo()
        self.home = GeoPoint(lat, lon, alt)
        self.core.nav.home = self.home_ned
        self.say(Severity.INFO, "Home position set")

    # ------------------------------------------------------------------ modes
    def set_mode(self, mode: FlightMode) -> CommandResult:
        with self._lock:
            return self._mode_locked(mode)

    def _mode_locked(self, mode: FlightMode) -> CommandResult:
        c = self.core
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
        if mode == FlightMode.OFFBOARD and not self.offboard_age_s() <= self.params["COM_OF_LOSS_T"]:
            return CommandResult.denied("Offboard denied: no setpoint received recently (stream setpoints first)")
        if mode == FlightMode.MISSION and not c.nav.items:
            return CommandResult.denied("Mission denied: no mission uploaded")
        if mode == FlightMode.RTL and self.home_ned is None:
            return CommandResult.denied("Return denied: no home position")
        if mode == FlightMode.OFFBOARD:
            self._offboard_apply()
        if mode == FlightMode.FOLLOW_TARGET:
            self.follow.enter()
        if self.failsafe and mode != c.mode:
            self.failsafe = Failsafe.NONE
        self.switch_mode(mode)
        return CommandResult.accepted()

    def _offboard_apply(self) -> None:
        nav = self.core.nav
        if self._offboard_kind == OffboardKind.ATTITUDE:
            nav.offboard_att = self._offboard_att
            nav.offboard_sp = None
        elif self._offboard_sp is not None:
            nav.set_offboard(self._offboard_sp)

    def takeoff(self, alt_m: float | None = None) -> CommandResult:
        with self._lock:
            c = self.core
            alt = self.params["MIS_TAKEOFF_ALT"] if alt_m is None or math.isnan(alt_m) else alt_m
            if not math.isfinite(alt) or not 0.5 <= alt <= 1000.0:
                return CommandResult.denied(f"Takeoff denied: altitude {alt_m} m outside [0.5, 1000] m")
            if not c.est.pos_valid:
                return CommandResult.rejected("Takeoff denied: no position estimate")
            c.nav.takeoff_alt_m = alt
            return self._mode_locked(FlightMode.TAKEOFF)

    def land(self) -> CommandResult:
        return self.set_mode(FlightMode.LAND)

    def return_to_launch(self) -> CommandResult:
        return self.set_mode(FlightMode.RTL)

    def hold(self) -> CommandResult:
        return self.set_mode(FlightMode.HOLD)

    # ------------------------------------------------------------------ missions
    def upload_mission(self, items: Sequence[MissionItem], kind: MissionKind = MissionKind.MISSION) -> CommandResult:
        why = check_mission(items, kind)
        if why:
            return CommandResult.denied(why) if not why.startswith("unsupported") else CommandResult.unsupported(why)
        with self._lock:
            nav = self.core.nav
            if kind == MissionKind.MISSION:
                nav.items = list(items)
                cur = next((i for i, it in enumerate(items) if it.current), 0)
                nav.current, nav.reached, nav.finished, nav.phase = cur, [], False, MissionPhase.START
            elif kind == MissionKind.FENCE:
                self.core.fence.set_items(items)
            else:
                self._rally = tuple(items)
            self._cache = None
            return CommandResult.accepted()

    def download_mission(self, kind: MissionKind = MissionKind.MISSION) -> tuple[MissionItem, ...]:
        with self._lock:
            if kind == MissionKind.MISSION:
                return tuple(self.core.nav.items)
            return self.core.fence.items if kind == MissionKind.FENCE else self._rally

    def clear_mission(self, kind: MissionKind = MissionKind.MISSION) -> CommandResult:
        return self.upload_mission((), kind)

    def set_current_item(self, seq: int) -> CommandResult:
        with self._lock:
            nav = self.core.nav
            if not 0 <= seq < len(nav.items):
                return CommandResult.denied(f"mission item {seq} does not exist ({len(nav.items)} items)")
            nav.current, nav.phase, nav.finished = seq, MissionPhase.START, False
            self._cache = None
            return CommandResult.accepted()

    def start_mission(self) -> CommandResult:
        return self.set_mode(FlightMode.MISSION)

    def pause_mission(self) -> CommandResult:
        return self.set_mode(FlightMode.HOLD)

    # ------------------------------------------------------------------ offboard and guided
    def set_offboard_setpoint(self, sp: OffboardSetpoint) -> CommandResult:
        vals = [v for vec in (sp.position_m, sp.velocity_m_s, sp.accel_m_s2) if vec is not None for v in vec]
        vals += [v for v in (sp.yaw_rad, sp.yaw_rate_rad_s) if v is not None]
        if not finite(vals):
            return CommandResult.denied("offboard setpoint with NaN or infinite values")
        return self._offboard_setpoint(sp)

    def set_offboard_axes(self, sp: OffboardSetpoint) -> CommandResult:
        """An offboard setpoint whose NaN components leave their axis to the others, as ALTCTL's setpoints do
        (ArduCopter's attitude targets: a horizontal acceleration and a climb rate). Infinite values are refused."""
        vals = [v for vec in (sp.position_m, sp.velocity_m_s, sp.accel_m_s2) if vec is not None for v in vec]
        if any(math.isinf(v) for v in vals) or all(math.isnan(v) for v in vals):
            return CommandResult.denied("offboard setpoint with infinite values or no axis set")
        return self._offboard_setpoint(sp)

    def _offboard_setpoint(self, sp: OffboardSetpoint) -> CommandResult:
        with self._lock:
            self._offboard_t_ns = self.core.t_ns
            self._offboard_sp, self._offboard_kind = sp, OffboardKind.SETPOINT
            if self.core.mode == FlightMode.OFFBOARD:
                self._offboard_apply()
            return CommandResult.accepted()

    def set_attitude_target(self, target: AttitudeTarget) -> CommandResult:
        vals = [target.thrust, *(target.quat or ()), *(target.body_rates_rad_s or ())]
        if not finite(vals) or not 0.0 <= target.thrust <= 1.0:
            return CommandResult.denied("attitude target with NaN values or thrust outside [0, 1]")
        if target.quat is not None and abs(math.sqrt(sum(v * v for v in target.quat)) - 1.0) > 0.05:
            return CommandResult.denied("attitude target quaternion is not normalised")
        with self._lock:
            self._offboard_t_ns = self.core.t_ns
            self._offboard_att, self._offboard_kind = target, OffboardKind.ATTITUDE
            if self.core.mode == FlightMode.OFFBOARD:
                self._offboard_apply()
            return CommandResult.accepted()

    def _flying(self) -> str:
        c = self.core
        if not c.armed or c.landed_state == LandedState.ON_GROUND:
            return "not flying (arm and take off first)"
        if c.est.ref is None:
            return "no global position"
        return ""

    def reposition(
        self, lat_deg: float | None, lon_deg: float | None, alt_amsl_m: float | None, yaw_rad: float | None = None
    ) -> CommandResult:
        with self._lock:
            why = self._flying()
            if why:
                return CommandResult.rejected(f"Reposition rejected: {why}")
            e = self.core.est
            ref = e.ref
            assert ref is not None
            lat0, lon0, alt0 = e.geo()
            lat = lat0 if lat_deg is None or math.isnan(lat_deg) else lat_deg
            lon = lon0 if lon_deg is None or math.isnan(lon_deg) else lon_deg
            alt = alt0 if alt_amsl_m is None or math.isnan(alt_amsl_m) else alt_amsl_m
            if not finite([lat, lon, alt]) or abs(lat) > 90 or abs(lon) > 180:
                return CommandResult.denied("Reposition denied: invalid coordinates")
            target = ref.to_ned(lat, lon, alt)
            yaw = None if yaw_rad is None or not math.isfinite(yaw_rad) else yaw_rad
            self.core.mode = FlightMode.HOLD
            self.core.nav.goto(target, yaw)
            self._cache = None
            return CommandResult.accepted()

    def orbit(
        self,
        radius_m: float,
        velocity_m_s: float,
        center_lat_deg: float | None = None,
        center_lon_deg: float | None = None,
        alt_amsl_m: float | None = None,
    ) -> CommandResult:
        with self._lock:
            why = self._flying()
            if why:
                return CommandResult.rejected(f"Orbit rejected: {why}")
            if not finite([radius_m, velocity_m_s]) or not 1.0 <= abs(radius_m) <= 10_000.0:
                return CommandResult.denied(f"Orbit denied: radius {radius_m} m outside [1, 10000] m")
            if abs(velocity_m_s) > self.params["MPC_XY_VEL_MAX"]:
                return CommandResult.denied(f"Orbit denied: speed {velocity_m_s} m/s above MPC_XY_VEL_MAX")
            e = self.core.est
            ref = e.ref
            assert ref is not None
            lat0, lon0, alt0 = e.geo()
            lat = lat0 if center_lat_deg is None or math.isnan(center_lat_deg) else center_lat_deg
            lon = lon0 if center_lon_deg is None or math.isnan(center_lon_deg) else center_lon_deg
            alt = alt0 if alt_amsl_m is None or math.isnan(alt_amsl_m) else alt_amsl_m
            n, east, d = ref.to_ned(lat, lon, alt)
            self.core.mode = FlightMode.ORBIT
            self.core.nav.start_orbit(Orbit(n, east, d, radius_m, velocity_m_s))
            self._cache = None
            return CommandResult.accepted()

    def set_yaw(self, yaw_rad: float | None) -> CommandResult:
        """Turn the nose to ``yaw_rad`` (rad from north) at the auto yaw rate and keep it there while the
        position target or velocity changes (ArduCopter's CONDITION_YAW and region of interest); None
        lets the active mode choose again. Until the next mode change."""
        if yaw_rad is not None and not math.isfinite(yaw_rad):
            return CommandResult.denied(f"yaw {yaw_rad} is not finite")
        with self._lock:
            why = self._flying()
            if why:
                return CommandResult.rejected(f"Yaw rejected: {why}")
            self.core.nav.yaw_target = None if yaw_rad is None else math.remainder(yaw_rad, math.tau)
            return CommandResult.accepted()

    def change_speed(self, speed_m_s: float) -> CommandResult:
        if not math.isfinite(speed_m_s) or not 0.0 < speed_m_s <= self.params["MPC_XY_VEL_MAX"]:
            return CommandResult.denied(f"speed {speed_m_s} m/s outside (0, MPC_XY_VEL_MAX]")
        with self._lock:
            self.core.nav.cruise_m_s = speed_m_s
            self._cache = None
            return CommandResult.accepted()

    def set_home(self, point: GeoPoint | None = None) -> CommandResult:
        with self._lock:
            e = self.core.est
            if e.ref is None:
                return CommandResult.rejected("no global position yet")
            if point is None:
                self._set_home_here()
            else:
                if not finite([point.lat_deg, point.lon_deg, point.alt_amsl_m]) or abs(point.lat_deg) > 90:
                    return CommandResult.denied("invalid home position")
                self.home = point
                self.home_ned = e.ref.to_ned(point.lat_deg, point.lon_deg, point.alt_amsl_m)
                self.core.nav.home = self.home_ned
            self._cache = None
            return CommandResult.accepted()

    # ------------------------------------------------------------------ parameters
    def get_param(self, name: str) -> float | int:
        return self.params.get(name)

    def set_param(self, name: str, value: float) -> CommandResult:
        return self.params.set(name, value)

    # ------------------------------------------------------------------ failures, sticks, follow target
    def inject_failure(self, unit: int, kind: int, instance: int) -> CommandResult:
        """MAV_CMD_INJECT_FAILURE (the MAVLink side checks ``SYS_FAILURE_EN``): ``harness.autopilot.failures``."""
        with self._lock:
            return self.failures.inject(unit, kind, instance)

    def manual_control(self, x: int, y: int, z: int, r: int) -> CommandResult:
        """One MANUAL_CONTROL (raw axes): ``harness.autopilot.manual``."""
        with self._lock:
            return self.manual.set_sticks(x, y, z, r)

    def follow_target(
        self, lat_deg: float, lon_deg: float, alt_amsl_m: float, vel_ned_m_s: tuple[float, float, float]
    ) -> CommandResult:
        """One FOLLOW_TARGET position of the target: ``harness.autopilot.follow``."""
        with self._lock:
            return self.follow.set_target(lat_deg, lon_deg, alt_amsl_m, vel_ned_m_s)

    def log_files(self) -> list[tuple[Path, int, int]]:
        """The flight logs to offer over MAVLink: (path, size in bytes up to the last whole message, start time
        in Unix seconds); the log being written is flushed first."""
        with self._lock:
            fl = self.flight_log
            if fl is None:
                return []
            return [(fl.path, fl.flush(), fl.start_unix_us // 1_000_000)]
