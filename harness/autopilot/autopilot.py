"""The autopilot of one vehicle: the flight core in lockstep, the commander around it (arming checks,
failsafes, home), and its services as MAVSDK's ``System`` composes plugins (``harness.autopilot.services``):

    action     ``action.Actions``               telemetry       ``telemetry.TelemetryFeed``
    mission    ``mission.MissionPlans``         bell            ``telemetry.TelemetryBell``
    offboard   ``offboard.OffboardInput``       failure         ``failures.FailureInjector``
    params     ``params.Params``                manual_control  ``manual.ManualControl``
    log_files  ``flightlog.FlightLogFiles``     follow_me       ``follow.FollowTarget``
    gripper    ``gripper.Grippers``             gimbal          ``gimbal.GimbalDevice``

``step(frame)`` runs once per tick in lockstep and returns the four motor commands; the services may be
called from any thread (the MAVLink side calls them on the wall clock). One lock (``lock``) serialises them:
a command changes the state between two steps and its effect shows in the next step.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping
from dataclasses import dataclass, field

from harness.autopilot.action import Actions
from harness.autopilot.api import (
    Failsafe,
    FlightMode,
    GeoPoint,
    LandedState,
    MissionReached,
    ModeStatus,
    Severity,
    StatusText,
    TickStatus,
)
from harness.autopilot.camera import CameraDevice
from harness.autopilot.events import VehicleEvent
from harness.autopilot.failures import FailureInjector
from harness.autopilot.flight import FlightCore
from harness.autopilot.flightlog import FlightLog, FlightLogFiles
from harness.autopilot.follow import FollowTarget
from harness.autopilot.gimbal import GimbalDevice
from harness.autopilot.gripper import Grippers
from harness.autopilot.manual import ManualControl
from harness.autopilot.mission import MissionPlans
from harness.autopilot.offboard import OffboardInput
from harness.autopilot.params import Params
from harness.autopilot.simworld import SimWorld
from harness.autopilot.supervisor import Supervisor
from harness.autopilot.telemetry import TelemetryBell, TelemetryFeed
from harness.core.clock import WALL, Clock
from harness.core.errors import ScenarioError
from harness.core.geo import GeoRef
from harness.fdm.frame import SensorFrame

_NO_EVENTS: list[VehicleEvent] = []
"""``take_events``'s answer when nothing happened (never changed: callers only read it)."""
_MODE_NUMBERS: dict[FlightMode, tuple[int, int]] = {m: (int(m.value[0]), int(m.value[1])) for m in FlightMode}
"""PX4 (main, sub) mode numbers of each flight mode, for END-TICK-AC (``FlightMode.value`` is an enum
property: computed once here instead of twice per tick)."""


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
    """One vehicle's autopilot: a ``harness.autopilot.services.System``."""

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
        self.lock = threading.Lock()
        self.home: GeoPoint | None = None
        self.home_ned: tuple[float, float, float] | None = None
        self.failsafe = Failsafe.NONE
        if not cfg.supervise_hz > 0:
            raise ScenarioError(f"autopilot {cfg.vehicle}: supervise_hz must be > 0, got {cfg.supervise_hz}")
        self._super_period_ns = round(1e9 / cfg.supervise_hz)
        self._next_super_ns = 0
        self.supervisor = Supervisor()
        self._numbered_mode: FlightMode | None = None
        self._mode_numbers = (0, 0)
        self.flight_log: FlightLog | None = None
        """The vehicle's ULog (``harness.autopilot.flightlog``), when the run writes one."""
        # the services (harness.autopilot.services.System)
        self.failure = FailureInjector(self)
        self.manual_control = ManualControl(self)
        self.follow_me = FollowTarget(self)
        self.offboard = OffboardInput(self)
        self.action = Actions(self, self.offboard, self.manual_control, self.follow_me)
        self.mission = MissionPlans(self, self.action)
        self.gripper = Grippers(self)
        self.gimbal = GimbalDevice(self)
        self.world = SimWorld(self.params, lambda: self.core.battery)
        self.camera = CameraDevice(self.lock)
        self.telemetry = TelemetryFeed(self, self.failure, self.gripper)
        self.bell = TelemetryBell()
        self.log_files = FlightLogFiles(self)
        self._hook_modes()

    def _hook_modes(self) -> None:
        nav = self.core.nav
        nav.set_mode_hook(FlightMode.POSCTL, self.manual_control.setpoint)
        nav.set_mode_hook(FlightMode.ALTCTL, self.manual_control.setpoint)
        nav.set_mode_hook(FlightMode.FOLLOW_TARGET, self.follow_me.update)

    # ------------------------------------------------------------------ lockstep
    def step(self, frame: SensorFrame) -> tuple[float, float, float, float]:
        with self.lock:
            c = self.core
            failure = self.failure
            self.manual_control.pre_step()
            world = self.world
            if world.active:  # SIM_* sensor and motor knobs (ArduPilot SITL's)
                frame = world.sensors(frame)
                motors = c.motors = world.motors(failure.motors(c.step(failure.sensors(frame))))
            else:
                motors = c.motors = failure.motors(c.step(failure.sensors(frame)))
            gimbal = self.gimbal
            if gimbal.used:
                gimbal.step(c.t_ns, c.est)
            nav = c.nav
            if nav.camera_items:  # the mission's camera items, re-issued to the camera as PX4 does
                for it in nav.take_camera_items():
                    self.camera.mission_item(it, c.t_ns)
            if self.camera.active:
                self.camera.home_alt_m = self.home.alt_amsl_m if self.home is not None else 0.0
                self.camera.step(c.t_ns, frame.truth, c.landed_state != LandedState.ON_GROUND)
            if self.flight_log is not None:
                self.flight_log.record(self)
            if c.t_ns >= self._next_super_ns:
                self._next_super_ns = c.t_ns + self._super_period_ns
                self.supervisor.check(self)
                failure.supervise()
                self.manual_control.supervise()
            nav = c.nav
            tel = self.telemetry
            if nav.new_reached:
                for s in nav.take_reached():
                    tel.reached.append(MissionReached(frame.t_ns, s))
                    self.say(Severity.INFO, f"Mission item {s} reached")
            if c.texts:
                for sev, text in c.texts:
                    self.say(Severity(sev), text)
                c.texts.clear()
            tel.cache = None
            ring = None
            bell = self.bell
            if bell.armed:
                ring = bell.due(c.t_ns, self._mode_status(), bool(tel.texts or tel.reached))
        if ring is not None:  # outside the lock: the MAVLink side reads the state through the locked services
            ring()
        return motors

    def take_events(self) -> list[VehicleEvent]:
        """What happened for the physics and the recordings since the last call (``harness.autopilot.events``):
        a SIM_* change (applied before the physics step after this tick), the camera's pictures."""
        if not (self.world.pending or self.camera.recorded):
            return _NO_EVENTS  # (every tick but a few: nothing made)
        out: list[VehicleEvent] = []
        if self.world.pending:
            change = self.world.take_change(self.core.t_ns)
            if change is not None:
                out.append(change)
        cam = self.camera
        if cam.recorded:
            out += cam.recorded
            cam.recorded = []
        return out

    def tick_status(self) -> TickStatus:
        """Armed, landed state, PX4 mode and the gimbal's attitude (None while unused), for END-TICK-AC
        (packed there by ``protocol.pack_status``)."""
        c = self.core
        mode = c.mode
        if mode is not self._numbered_mode:  # (an enum's hash is a Python call: looked up on a change only)
            self._numbered_mode = mode
            self._mode_numbers = _MODE_NUMBERS[mode]
        main, sub = self._mode_numbers
        return (c.armed, int(c.landed_state) if c.armed else 1, main, sub, self.gimbal.report)

    def _mode_status(self) -> ModeStatus:
        """What rings the bell on a change: the tick's status without the gimbal (a moving gimbal is no news)."""
        armed, landed, main, sub, _ = self.tick_status()
        return (armed, landed, main, sub)

    # ------------------------------------------------------------------ the commander (services and supervisor, under the lock)
    def say(self, severity: Severity, text: str) -> None:
        self.telemetry.texts.append(StatusText(max(self.core.t_ns, 0), severity, text))
        if self.flight_log is not None:
            self.flight_log.text(self.core.t_ns, severity, text)

    def switch_mode(self, mode: FlightMode) -> None:
        c = self.core
        if c.mode != mode or mode in (FlightMode.TAKEOFF, FlightMode.HOLD, FlightMode.RTL):
            c.mode = mode
            c.nav.enter(mode, c.landed_state == LandedState.ON_GROUND)
        self.telemetry.cache = None

    def state_changed(self) -> None:
        self.telemetry.cache = None

    def to_local(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        ref = self.core.est.ref
        if ref is None:
            return (math.nan, math.nan)
        n, e, _ = ref.to_ned(lat_deg, lon_deg, ref.alt_m)
        return (n, e)

    def cut_motors(self, why: str) -> None:
        c = self.core
        c.armed = False
        c.motors = (0.0, 0.0, 0.0, 0.0)
        self.supervisor.reset()
        self.say(Severity.INFO, why)
        self.telemetry.cache = None

    def restart(self) -> None:
        old = self.core
        cfg = self.config
        self.core = FlightCore(self.params, cfg.use_ground_truth, GeoRef(*cfg.origin) if cfg.origin else None)
        self.core.nav.load_mission(old.nav.items)
        self.core.fence.set_items(old.fence.items)
        self.core.t_ns = old.t_ns
        self.home = self.home_ned = None
        self.failsafe = Failsafe.NONE
        self.supervisor = Supervisor()
        self.offboard.reset()
        self.manual_control.reset()
        self.follow_me.reset()
        self._hook_modes()
        self.telemetry.cache = None

    def set_home_here(self) -> None:
        e = self.core.est
        self.home_ned = (e.pn, e.pe, e.pd)
        lat, lon, alt = e.geo()
        self.home = GeoPoint(lat, lon, alt)
        self.core.nav.set_home(self.home_ned)
        self.say(Severity.INFO, "Home position set")
