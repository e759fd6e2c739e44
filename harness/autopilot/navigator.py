"""Flight modes as setpoint generators: hold, goto, takeoff, land, return, orbit, offboard, and missions.

The navigator turns the active mode into a ``TrajectorySetpoint`` for the position controller each
control step. It does not arm, disarm or pick modes: it reports what happened (``reached``, ``landing``,
``done``) and the commander (``autopilot.py``) decides.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from harness.autopilot.api import (
    CAMERA_MISSION_COMMANDS,
    SKIPPED_MISSION_COMMANDS,
    AttitudeTarget,
    FlightMode,
    MavCmd,
    MavFrame,
    MissionItem,
    OffboardFrame,
    OffboardSetpoint,
)
from harness.autopilot.control import NAN, TrajectorySetpoint
from harness.autopilot.estimator import Estimator
from harness.autopilot.params import Params
from harness.autopilot.trajectory import PointTracker, slew_yaw
from harness.core.geo import Vec3


@dataclass(slots=True)
class Orbit:
    cx: float
    cy: float
    z: float
    radius_m: float
    velocity_m_s: float
    theta: float = 0.0


class MissionPhase(enum.Enum):
    """Where the mission stands on its current item."""

    NONE = enum.auto()
    START = enum.auto()
    """The item is about to begin (its target is set on the next step)."""
    PRE_TAKEOFF = enum.auto()
    """Climbing before the first item, which is not a takeoff."""
    TAKEOFF = enum.auto()
    GOTO = enum.auto()
    WAIT = enum.auto()
    """At the item, holding for its time (or a NAV_DELAY)."""
    LAND = enum.auto()
    RTL = enum.auto()
    """A NAV_RETURN_TO_LAUNCH item: the return's own phase is ``rtl_phase``."""


class RtlPhase(enum.Enum):
    """The return: climb to the return altitude, fly home, land."""

    NONE = enum.auto()
    CLIMB = enum.auto()
    RETURN = enum.auto()
    LAND = enum.auto()


class Navigator:
    def __init__(self, params: Params, est: Estimator, on_text: Callable[[int, str], None]) -> None:
        self.params = params
        self.est = est
        self.text = on_text
        self.sp = TrajectorySetpoint()
        self.tr = PointTracker()
        self.home: Vec3 = (0.0, 0.0, 0.0)
        self.mode = FlightMode.HOLD
        self.target: Vec3 = (0.0, 0.0, 0.0)
        self.yaw_sp = 0.0
        self.yaw_target: float | None = None
        self.cruise_m_s = params["MPC_XY_CRUISE"]
        self.phase = MissionPhase.NONE
        self.rtl_phase = RtlPhase.NONE
        self.landing = False
        """The active mode is descending to land (land detector may declare touchdown)."""
        self.wants_climb = False
        """The active mode is taking off from the ground."""
        self.timer_s = 0.0
        self.orbit_cfg: Orbit | None = None
        self.offboard_sp: OffboardSetpoint | None = None
        self.offboard_att: AttitudeTarget | None = None
        self.manual_att: AttitudeTarget | None = None
        """Attitude and thrust from the sticks in STABILIZED / MANUAL (``harness.autopilot.manual``)."""
        self.mode_hooks: dict[FlightMode, Callable[[float], None]] = {}
        """Modes whose setpoint another module makes (sticks, follow target): called with dt every update."""
        self._offboard_pos: Vec3 | None = None
        # mission
        self.items: list[MissionItem] = []
        self.current = 0
        self.reached: list[int] = []
        self.finished = False
        self.new_reached: list[int] = []
        self.camera_items: list[MissionItem] = []
        """The mission's camera items passed since the autopilot last took them (``take_camera_items``)."""
        self.mission_done = False

    # ---------- helpers ----------
    def pos(self) -> Vec3:
        e = self.est
        return (e.pn, e.pe, e.pd)

    def _start_tracker(self) -> None:
        e = self.est
        self.tr.reset((e.pn, e.pe, e.pd), (e.vn, e.ve, e.vd))

    def track(self, target: Vec3, dt: float, v_xy: float | None = None, v_dn: float | None = None) -> None:
        """Fly the smooth setpoint towards ``target`` this step (the modes made elsewhere call it too)."""
        p = self.params
        self.tr.step(
            target[0],
            target[1],
            target[2],
            self.cruise_m_s if v_xy is None else v_xy,
            p["MPC_Z_VEL_MAX_UP"] if not self.wants_climb else p["MPC_TKO_SPEED"],
            p["MPC_Z_VEL_MAX_DN"] if v_dn is None else v_dn,
            p["MPC_ACC_HOR"],
            1.5,
            dt,
        )
        t = self.tr
        self.sp.set((t.x, t.y, t.z), (t.vx, t.vy, t.vz), (t.ax, t.ay, t.az), self.yaw_sp)

    def _yaw(self, dt: float) -> None:
        if self.yaw_target is not None:
            self.yaw_sp, _ = slew_yaw(self.yaw_sp, self.yaw_target, math.radians(self.params["MPC_YAWRAUTO_MAX"]), dt)

    def item_target(self, it: MissionItem) -> Vec3:
        """An item's position in the local frame (NaN components where the item leaves them open)."""
        e = self.est
        cur = self.pos()
        if it.frame in (MavFrame.LOCAL_NED, MavFrame.LOCAL_OFFSET_NED):
            return (float(it.x), float(it.y), float(it.z))
        if it.is_global and e.ref is not None:
            lat, lon = it.lat_deg, it.lon_deg
            home_alt = e.ref.alt_m - self.home[2]
            alt = home_alt + it.z if it.is_relative_alt else it.z
            n, east, d = e.ref.to_ned(lat, lon, alt)
            if lat == 0.0 and lon == 0.0:
                n, east = cur[0], cur[1]
            return (n, east, d)
        return cur

    # ---------- mode entry ----------
    def enter(self, mode: FlightMode, landed: bool) -> None:
        prev, prev_target = self.mode, self.target
        self.mode = mode
        self.landing = False
        self.wants_climb = False
        self.phase = MissionPhase.NONE
        self.rtl_phase = RtlPhase.NONE
        self.timer_s = 0.0
        self.yaw_sp = self.est.yaw
        self.yaw_target = None
        self._start_tracker()
        if mode in (FlightMode.HOLD, FlightMode.POSCTL, FlightMode.ALTCTL):
            self.target = self._stop_point()
            if prev == FlightMode.TAKEOFF and not landed:
                self.target = (self.target[0], self.target[1], prev_target[2])  # loiter at the takeoff altitude
        elif mode == FlightMode.TAKEOFF:
            alt = self.takeoff_alt_m
            self.target = (self.est.pn, self.est.pe, self.home[2] - alt)
            self.wants_climb = landed
        elif mode == FlightMode.LAND:
            self.target = self.pos()
            self.landing = True
        elif mode == FlightMode.RTL:
            self._rtl_start()
        elif mode == FlightMode.MISSION:
            if self.finished or self.current >= len(self.items):
                self.current = 0
                self.reached = []
                self.finished = False
            self.phase = MissionPhase.START
        elif mode == FlightMode.OFFBOARD:
            self._offboard_pos = None

    takeoff_alt_m = 2.5

    # ---------- commands (the commander and the modes made elsewhere give them; nothing else writes fields) ----------
    def load_mission(self, items: Sequence[MissionItem]) -> None:
        """A new mission: start at the item marked current (else the first), nothing reached."""
        self.items = list(items)
        cur = next((i for i, it in enumerate(items) if it.current), 0)
        self.current, self.reached, self.finished, self.phase = cur, [], False, MissionPhase.START

    def set_current(self, seq: int) -> None:
        """Go on with item ``seq`` (an index into ``items``)."""
        self.current, self.phase, self.finished = seq, MissionPhase.START, False

    def set_home(self, home_ned: Vec3) -> None:
        self.home = home_ned

    def set_takeoff_alt(self, alt_m: float) -> None:
        self.takeoff_alt_m = alt_m

    def set_cruise(self, speed_m_s: float) -> None:
        self.cruise_m_s = speed_m_s

    def point_nose(self, yaw_rad: float | None) -> None:
        """Turn to ``yaw_rad`` at the auto yaw rate and keep it (None: the mode chooses)."""
        self.yaw_target = yaw_rad

    def fly_attitude(self, target: AttitudeTarget | None) -> None:
        """OFFBOARD flies this attitude target instead of a position / velocity setpoint."""
        self.offboard_att = target
        self.offboard_sp = None

    def set_manual_attitude(self, target: AttitudeTarget | None) -> None:
        """The sticks' attitude and thrust in STABILIZED / MANUAL (None: not flying on the sticks)."""
        self.manual_att = target

    def set_vertical_intent(self, wants_climb: bool, landing: bool) -> None:
        """The sticks ask to leave the ground / to land (what the land detector and the motors idle check read)."""
        self.wants_climb = wants_climb
        self.landing = landing

    def point_to(self, yaw_rad: float) -> None:
        """This step's yaw setpoint (a mode made elsewhere pointing the nose at something)."""
        self.yaw_sp = yaw_rad

    def set_mode_hook(self, mode: FlightMode, hook: Callable[[float], None]) -> None:
        """Let ``hook(dt)`` make the setpoint in ``mode`` (sticks, follow target): it calls :meth:`track`."""
        self.mode_hooks[mode] = hook

    def take_camera_items(self) -> list[MissionItem]:
        out, self.camera_items = self.camera_items, []
        return out

    def take_reached(self) -> list[int]:
        """Items reached since the last call."""
        out = self.new_reached
        self.new_reached = []
        return out

    def take_mission_done(self) -> bool:
        """Whether the mission finished since the last call."""
        done = self.mission_done
        self.mission_done = False
        return done

    def _stop_point(self) -> Vec3:
        e = self.est
        return (e.pn, e.pe, e.pd)

    def goto(self, target: Vec3, yaw: float | None) -> None:
        """Reposition: hold at a new target (PX4's DO_REPOSITION)."""
        self.mode = FlightMode.HOLD
        self.landing = self.wants_climb = False
        self.target = target
        self.yaw_target = yaw

    def start_orbit(self, orbit: Orbit) -> None:
        e = self.est
        self.mode = FlightMode.ORBIT
        self.landing = self.wants_climb = False
        orbit.theta = math.atan2(e.pe - orbit.cy, e.pn - orbit.cx)
        self.orbit_cfg = orbit
        self._start_tracker()

    # ---------- per-step ----------
    def update(self, dt: float, landed: bool) -> TrajectorySetpoint:
        m = self.mode
        self._yaw(dt)
        hook = self.mode_hooks.get(m)
        if hook is not None:
            hook(dt)
            return self.sp
        if m in (FlightMode.HOLD, FlightMode.POSCTL, FlightMode.ALTCTL, FlightMode.TAKEOFF):
            self.track(self.target, dt)
        elif m == FlightMode.LAND:
            self._land(dt)
        elif m == FlightMode.RTL:
            self._rtl(dt, landed)
        elif m == FlightMode.MISSION:
            self._mission(dt, landed)
        elif m == FlightMode.ORBIT:
            self._orbit(dt)
        elif m == FlightMode.OFFBOARD:
            self._offboard()
        return self.sp

    def takeoff_reached(self) -> bool:
        return abs(self.est.pd - self.target[2]) < self.params["NAV_MC_ALT_RAD"] and abs(self.est.vd) < 0.5

    def _land(self, dt: float) -> None:
        p = self.params
        rel = self.home[2] - self.est.pd
        a1, a2, slow = p["MPC_LAND_ALT1"], p["MPC_LAND_ALT2"], p["MPC_LAND_SPEED"]
        fast = p["MPC_Z_VEL_MAX_DN"]
        if rel > a1:
            v = fast
        elif rel > a2 and a1 > a2:
            v = slow + (fast - slow) * (rel - a2) / (a1 - a2)
        else:
            v = slow
        if not self.est.pos_valid:  # no position (GPS lost): PX4's Descend, level and straight down
            self.sp.set((NAN, NAN, NAN), (NAN, NAN, v), (0.0, 0.0, NAN), self.yaw_sp)
            return
        self.tr.step(self.target[0], self.target[1], self.tr.z, 1.0, 1.0, 1.0, p["MPC_ACC_HOR"], 1.0, dt)
        self.sp.set((self.tr.x, self.tr.y, NAN), (0.0, 0.0, v), (NAN, NAN, NAN), self.yaw_sp)

    # ---------- return ----------
    def _rtl_start(self) -> None:
        p = self.params
        e = self.est
        dist = math.hypot(e.pn - self.home[0], e.pe - self.home[1])
        if dist < p["RTL_MIN_DIST"]:
            self.rtl_phase = RtlPhase.RETURN
            self.target = (self.home[0], self.home[1], e.pd)
        else:
            self.rtl_phase = RtlPhase.CLIMB
            alt = max(self.home[2] - e.pd, p["RTL_RETURN_ALT"])
            self.target = (e.pn, e.pe, self.home[2] - alt)
        self.landing = False

    def _rtl(self, dt: float, landed: bool) -> bool:
        """One RTL step; True once it has landed."""
        if self.rtl_phase == RtlPhase.CLIMB:
            self.track(self.target, dt)
            if abs(self.est.pd - self.target[2]) < self.params["NAV_MC_ALT_RAD"]:
                self.rtl_phase = RtlPhase.RETURN
                self.target = (self.home[0], self.home[1], self.target[2])
                self.yaw_target = math.atan2(self.home[1] - self.est.pe, self.home[0] - self.est.pn)
        elif self.rtl_phase == RtlPhase.RETURN:
            self.track(self.target, dt)
            e = self.est
            if math.hypot(e.pn - self.target[0], e.pe - self.target[1]) < 0.5 and math.hypot(e.vn, e.ve) < 0.5:
                self.rtl_phase = RtlPhase.LAND
                self.landing = True
                self.yaw_target = None
        elif self.rtl_phase == RtlPhase.LAND:
            self._land(dt)
            return landed
        return False

    # ---------- orbit ----------
    def _orbit(self, dt: float) -> None:
        o = self.orbit_cfg
        if o is None:
            return
        r = abs(o.radius_m)
        v = o.velocity_m_s if o.radius_m >= 0 else -o.velocity_m_s
        w = v / r
        o.theta += w * dt
        c, s = math.cos(o.theta), math.sin(o.theta)
        px, py = o.cx + r * c, o.cy + r * s
        vx, vy = -s * v, c * v
        a = v * v / r
        self.yaw_sp = math.atan2(o.cy - py, o.cx - px)
        self.tr.step(self.tr.x, self.tr.y, o.z, 1.0, 1.0, 1.0, 1.0, 1.5, dt)
        self.sp.set((px, py, self.tr.z), (vx, vy, self.tr.vz), (-a * c, -a * s, NAN), self.yaw_sp, w)

    # ---------- offboard ----------
    def _offboard(self) -> None:
        sp = self.offboard_sp
        if sp is None:
            return
        e = self.est
        yaw = e.yaw
        c, s = math.cos(yaw), math.sin(yaw)
        body = sp.frame == OffboardFrame.BODY_NED

        def rot(v: Vec3) -> Vec3:
            return (c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]) if body else v

        pos: Vec3 = (NAN, NAN, NAN)
        if sp.position_m is not None:
            if body:
                if self._offboard_pos is None:
                    off = rot(sp.position_m)
                    self._offboard_pos = (e.pn + off[0], e.pe + off[1], e.pd + off[2])
                pos = self._offboard_pos
            else:
                pos = sp.position_m
        vel = rot(sp.velocity_m_s) if sp.velocity_m_s is not None else (NAN, NAN, NAN)
        acc = rot(sp.accel_m_s2) if sp.accel_m_s2 is not None else (NAN, NAN, NAN)
        if sp.yaw_rad is not None:
            self.yaw_sp = sp.yaw_rad
        yr = sp.yaw_rate_rad_s if sp.yaw_rate_rad_s is not None else NAN
        self.sp.set(pos, vel, acc, self.yaw_sp if sp.yaw_rate_rad_s is None else NAN, yr)

    def set_offboard(self, sp: OffboardSetpoint) -> None:
        self.offboard_sp = sp
        self.offboard_att = None
        self._offboard_pos = None

    # ---------- mission ----------
    def _mission(self, dt: float, landed: bool) -> None:
        p = self.params
        e = self.est
        while self.current < len(self.items):
            it = self.items[self.current]
            cmd = it.command
            if cmd in SKIPPED_MISSION_COMMANDS or cmd not in _NAV_COMMANDS:
                if cmd == MavCmd.DO_CHANGE_SPEED and it.param2 > 0:
                    self.cruise_m_s = float(it.param2)
                elif cmd in CAMERA_MISSION_COMMANDS:
                    self.camera_items.append(it)
                self._reach()
                continue
            break
        if self.current >= len(self.items):
            if not self.finished:
                self.finished = True
                self.mission_done = True
            self.track(self.target, dt)
            return
        it = self.items[self.current]
        cmd = it.command
        if self.phase == MissionPhase.START:
            self._start_tracker()
            tgt = self.item_target(it)
            if cmd == MavCmd.NAV_TAKEOFF or (landed and cmd not in (MavCmd.NAV_LAND, MavCmd.NAV_RETURN_TO_LAUNCH)):
                alt = (
                    max(self.home[2] - tgt[2], p["MIS_TAKEOFF_ALT"])
                    if cmd != MavCmd.NAV_TAKEOFF
                    else (self.home[2] - tgt[2])
                )
                self.target = (e.pn, e.pe, self.home[2] - alt)
                self.phase = MissionPhase.TAKEOFF if cmd == MavCmd.NAV_TAKEOFF else MissionPhase.PRE_TAKEOFF
                self.wants_climb = landed
            elif cmd == MavCmd.NAV_RETURN_TO_LAUNCH:
                self._rtl_start()
                self.phase = MissionPhase.RTL
            elif cmd == MavCmd.NAV_DELAY:
                self.target = self.pos()
                self.timer_s = max(float(it.param1), 0.0)
                self.phase = MissionPhase.WAIT
            else:
                self.target = (tgt[0], tgt[1], e.pd if cmd == MavCmd.NAV_LAND else tgt[2])
                self.phase = MissionPhase.GOTO
                d = math.hypot(tgt[0] - e.pn, tgt[1] - e.pe)
                if d > 2.0:
                    self.yaw_target = math.atan2(tgt[1] - e.pe, tgt[0] - e.pn)
        ph = self.phase
        if ph in (MissionPhase.TAKEOFF, MissionPhase.PRE_TAKEOFF):
            self.track(self.target, dt)
            if self.takeoff_reached():
                self.wants_climb = False
                if ph == MissionPhase.TAKEOFF:
                    self._reach()
                self.phase = MissionPhase.START
        elif ph == MissionPhase.GOTO:
            self.track(self.target, dt)
            rad = float(it.param2) if cmd == MavCmd.NAV_WAYPOINT and it.param2 > 0 else p["NAV_ACC_RAD"]
            dh = math.hypot(self.target[0] - e.pn, self.target[1] - e.pe)
            if dh < rad and abs(self.target[2] - e.pd) < p["NAV_MC_ALT_RAD"] and self._setpoint_arrived():
                if cmd == MavCmd.NAV_LAND:
                    self.phase = MissionPhase.LAND
                    self.landing = True
                else:
                    hold = it.param1 if cmd in (MavCmd.NAV_WAYPOINT, MavCmd.NAV_LOITER_TIME) else 0.0
                    self.timer_s = max(float(hold), 0.0)
                    self.phase = MissionPhase.WAIT
                    self.new_reached.append(it.seq)
                    self.reached.append(it.seq)
        elif ph == MissionPhase.WAIT:
            self.track(self.target, dt)
            self.timer_s -= dt
            if self.timer_s <= 0.0:
                if cmd == MavCmd.NAV_DELAY:
                    self._reach()
                else:
                    self._advance()
        elif ph == MissionPhase.LAND:
            self._land(dt)
            if landed:
                self.landing = False
                self._reach()
        elif ph == MissionPhase.RTL:
            done = self._rtl(dt, landed)
            if done:
                self.landing = False
                self._reach()

    def _setpoint_arrived(self) -> bool:
        """The smooth setpoint has stopped on the target (so a turn starts from rest, without overshoot)."""
        t = self.tr
        return abs(t.x - self.target[0]) < 0.05 and abs(t.y - self.target[1]) < 0.05 and abs(t.vx) + abs(t.vy) < 0.05

    def _reach(self) -> None:
        seq = self.items[self.current].seq
        self.new_reached.append(seq)
        self.reached.append(seq)
        self._advance()

    def _advance(self) -> None:
        self.current += 1
        self.phase = MissionPhase.START
        self.yaw_target = None


_NAV_COMMANDS = frozenset(
    {
        MavCmd.NAV_WAYPOINT,
        MavCmd.NAV_TAKEOFF,
        MavCmd.NAV_LAND,
        MavCmd.NAV_RETURN_TO_LAUNCH,
        MavCmd.NAV_LOITER_TIME,
        MavCmd.NAV_DELAY,
    }
)
SUPPORTED_MISSION_COMMANDS = _NAV_COMMANDS | SKIPPED_MISSION_COMMANDS
