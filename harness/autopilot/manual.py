"""Manual control: MANUAL_CONTROL sticks fly POSCTL, ALTCTL, STABILIZED and MANUAL as PX4 does, and the RC
loss failsafe.

Sticks (PX4's ``manual_control_setpoint`` from MAVLink MANUAL_CONTROL): ``x`` pitch (forward +), ``y`` roll
(right +), ``r`` yaw (clockwise +), each −1000…1000 → −1…1; ``z`` throttle 0…1000 → 0…1, 0.5 = centre.
A deadzone of ``MPC_HOLD_DZ`` around the centre of every stick (throttle: around 0.5) reads as centred.

- **POSCTL** (PX4's position mode): horizontal sticks → velocity in the heading frame, full stick
  ``MPC_VEL_MANUAL``; centred → brake and hold the position. Throttle above / below centre → climb at up to
  ``MPC_Z_VEL_MAX_UP`` / descend at up to ``MPC_Z_VEL_MAX_DN``; centred → hold the altitude. Yaw stick → yaw
  rate, full stick ``MPC_MAN_Y_MAX``.
- **ALTCTL**: horizontal sticks → tilt (full stick ``MPC_MAN_TILT_MAX``) as a horizontal acceleration, no
  position hold (the vehicle drifts with the wind); vertical and yaw as in POSCTL.
- **STABILIZED** and **MANUAL** (a multicopter's MANUAL is stabilized, as in PX4): sticks → attitude (tilt
  ``MPC_MAN_TILT_MAX``), yaw rate; throttle → collective thrust, ``MPC_MANTHR_MIN`` at zero, the hover
  thrust at centre, ``MPC_THR_MAX`` at full (PX4's ``MPC_THR_CURVE`` 0).

Without stick input within ``COM_RC_LOSS_T`` (sim time) these modes are refused, as PX4 refuses them
without a valid manual control setpoint; ``COM_RC_IN_MODE`` 4 ignores MANUAL_CONTROL altogether. RC loss
after sticks were used: in a stick mode, ``NAV_RCL_ACT`` (1 hold, 2 return, 3 land, 5 terminate = land,
6 disarm; 0 = hold, PX4's fallback when the mode cannot run); in other modes ``NAV_RCL_ACT`` unless
``COM_RCL_EXCEPT`` exempts the mode (bit 0 mission, 1 hold, 2 offboard).
"""

from __future__ import annotations

import math
from typing import Protocol

from harness.autopilot.api import AttitudeTarget, CommandResult, Failsafe, FlightMode, LandedState, Severity
from harness.autopilot.control import NAN
from harness.autopilot.mathutil import G_M_S2
from harness.autopilot.supervisor import Commander
from harness.core.geo import quat_from_euler


class _RcSignal(Protocol):
    @property
    def rc_off(self) -> bool: ...


class ManualHost(Commander, Protocol):
    """What manual control reads of, and does to, its autopilot (``harness.autopilot.Autopilot``)."""

    @property
    def failure(self) -> _RcSignal: ...


STICK_MODES = frozenset({FlightMode.POSCTL, FlightMode.ALTCTL, FlightMode.STABILIZED, FlightMode.MANUAL})
_ATTITUDE_MODES = frozenset({FlightMode.STABILIZED, FlightMode.MANUAL})
_INVALID_AXIS = 0x7FFF


def deadzone(v: float, dz: float) -> float:
    """PX4's ``math::deadzone``: 0 inside ±dz, rescaled to reach ±1 at full stick outside it."""
    v = -1.0 if v < -1.0 else (1.0 if v > 1.0 else v)
    if abs(v) <= dz or dz >= 1.0:
        return 0.0
    return math.copysign((abs(v) - dz) / (1.0 - dz), v)


def _rotate_heading(fwd: float, right: float, yaw: float) -> tuple[float, float]:
    c, s = math.cos(yaw), math.sin(yaw)
    return (fwd * c - right * s, fwd * s + right * c)


class ManualControl:
    """The sticks of one vehicle and the stick modes: the autopilot's ``manual_control`` service. ``set_sticks``
    takes the autopilot's lock; the rest is called by the autopilot under it."""

    def __init__(self, ap: ManualHost) -> None:
        self.ap = ap
        self.reset()

    def reset(self) -> None:
        """As at boot: centred sticks, none received (a reboot of the flight stack)."""
        self.x = self.y = self.r = 0.0
        self.z = 0.5
        self.last_ns: int | None = None
        """Sim time of the last MANUAL_CONTROL (None: never)."""
        self.lost = False
        self._hold: tuple[float, float, float] | None = None
        self._yaw = 0.0
        self._yaw_sp = 0.0
        self._t_ns = -1
        self._sticks: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)

    # ------------------------------------------------------------------ input
    def set_sticks(self, x: int, y: int, z: int, r: int) -> CommandResult:
        """One MANUAL_CONTROL (raw −1000…1000 axes; 0x7FFF = axis not present)."""
        with self.ap.lock:
            return self._set_sticks(x, y, z, r)

    def _set_sticks(self, x: int, y: int, z: int, r: int) -> CommandResult:
        if int(self.ap.params["COM_RC_IN_MODE"]) == 4:
            return CommandResult.denied("manual control ignored: COM_RC_IN_MODE is 4")
        axes = (x, y, z, r)
        if any(not -1000 <= a <= 1000 for a in axes if a != _INVALID_AXIS):
            return CommandResult.denied(f"manual control axes {axes} outside [-1000, 1000]")
        self.x = 0.0 if x == _INVALID_AXIS else x / 1000.0
        self.y = 0.0 if y == _INVALID_AXIS else y / 1000.0
        self.z = 0.5 if z == _INVALID_AXIS else min(max(z / 1000.0, 0.0), 1.0)
        self.r = 0.0 if r == _INVALID_AXIS else r / 1000.0
        self.last_ns = max(self.ap.core.t_ns, 0)
        if self.lost:
            self.lost = False
            self.ap.say(Severity.INFO, "Manual control regained")
        return CommandResult.accepted()

    def fresh(self) -> bool:
        """A stick input within ``COM_RC_LOSS_T`` of sim time (and not cut by an injected RC failure)."""
        if self.last_ns is None or self.ap.failure.rc_off:
            return False
        return (max(self.ap.core.t_ns, 0) - self.last_ns) * 1e-9 <= self.ap.params["COM_RC_LOSS_T"]

    def refuse(self, mode: FlightMode) -> CommandResult | None:
        """Why ``mode`` may not be entered now (None: it may)."""
        if mode not in STICK_MODES or self.fresh():
            return None
        if int(self.ap.params["COM_RC_IN_MODE"]) == 4:
            if mode in _ATTITUDE_MODES:
                return CommandResult.denied(f"{mode.name} needs a manual control input (RC); none is configured")
            return None  # no RC by configuration: position and altitude modes hold, as before sticks existed
        return CommandResult.denied(f"{mode.name} denied: no manual control input (RC); send MANUAL_CONTROL")

    def refusal(self, mode: FlightMode) -> str:
        """Why ``mode`` may not be flown without its manual control input ('' when it may)."""
        refused = self.refuse(mode)
        return "" if refused is None else refused.reason

    # ------------------------------------------------------------------ per tick (before the flight core)
    def pre_step(self) -> None:
        ap = self.ap
        c = ap.core
        nav = c.nav
        if self.last_ns is None or not c.armed or c.mode not in STICK_MODES:
            nav.set_manual_attitude(None)
            self._hold = None
            return
        p = ap.params
        dz = p["MPC_HOLD_DZ"]
        fwd, right, yaw_in = deadzone(self.x, dz), deadzone(self.y, dz), deadzone(self.r, dz)
        thr = deadzone(self.z * 2.0 - 1.0, dz)  # -1 … 1, 0 = centre
        on_ground = c.landed_state == LandedState.ON_GROUND
        nav.set_vertical_intent(on_ground and thr > 0.0, thr < -0.5 and not on_ground)
        yaw_rate = yaw_in * math.radians(p["MPC_MAN_Y_MAX"])
        if c.mode in _ATTITUDE_MODES:
            self._attitude(fwd, right, thr, yaw_rate)
            return
        nav.set_manual_attitude(None)
        self._sticks = (fwd, right, thr, yaw_rate)

    def _attitude(self, fwd: float, right: float, thr: float, yaw_rate: float) -> None:
        c = self.ap.core
        p = self.ap.params
        tilt = math.radians(p["MPC_MAN_TILT_MAX"])
        if c.nav.manual_att is None:
            self._yaw_sp = c.est.yaw
        dt = (c.t_ns - self._t_ns) * 1e-9 if 0 <= self._t_ns < c.t_ns else 0.0
        self._t_ns = c.t_ns
        self._yaw_sp = math.remainder(self._yaw_sp + yaw_rate * min(dt, 0.05), math.tau)
        hover, tmin, tmax = c.hover_thrust, p["MPC_MANTHR_MIN"], p["MPC_THR_MAX"]
        thrust = hover + thr * ((tmax - hover) if thr > 0 else (hover - tmin))
        if c.landed_state == LandedState.ON_GROUND and thr <= 0.0:
            thrust = 0.0
        q = quat_from_euler(right * tilt, -fwd * tilt, self._yaw_sp)
        c.nav.set_manual_attitude(AttitudeTarget(q, thrust, (0.0, 0.0, yaw_rate)))

    def setpoint(self, dt: float) -> None:
        """POSCTL / ALTCTL: the navigator's setpoint from the sticks (the navigator calls it every update)."""
        c = self.ap.core
        nav = c.nav
        if self.last_ns is None:  # COM_RC_IN_MODE 4 (no sticks, e.g. the ArduCopter personality): hold
            nav.track(nav.target, dt)
            return
        p = self.ap.params
        e = c.est
        fwd, right, thr, yaw_rate = self._sticks
        if self._hold is None:
            self._hold = (e.pn, e.pe, e.pd)
            self._yaw = e.yaw
        hn, he, hd = self._hold
        if thr != 0.0:  # climb or descend at the stick's rate; the altitude is held where the stick centres
            hd = e.pd
            pz, vz = NAN, -thr * (p["MPC_Z_VEL_MAX_UP"] if thr > 0 else p["MPC_Z_VEL_MAX_DN"])
        else:
            pz, vz = hd, 0.0
        self._yaw = math.remainder(self._yaw + yaw_rate * dt, math.tau)
        if c.mode == FlightMode.ALTCTL:
            a = G_M_S2 * math.tan(math.radians(p["MPC_MAN_TILT_MAX"]))
            an, ae = _rotate_heading(fwd * a, right * a, e.yaw)
            hn, he = e.pn, e.pe
            nav.sp.set((NAN, NAN, pz), (NAN, NAN, vz), (an, ae, NAN), self._yaw)
        elif fwd != 0.0 or right != 0.0:
            v = p["MPC_VEL_MANUAL"]
            vn, ve = _rotate_heading(fwd * v, right * v, e.yaw)
            hn, he = e.pn, e.pe
            nav.sp.set((NAN, NAN, pz), (vn, ve, vz), (NAN, NAN, NAN), self._yaw)
        elif math.hypot(e.vn, e.ve) > p["MPC_HOLD_MAX_XY"]:  # sticks centred: brake, then lock the position
            hn, he = e.pn, e.pe
            nav.sp.set((NAN, NAN, pz), (0.0, 0.0, vz), (NAN, NAN, NAN), self._yaw)
        else:
            nav.sp.set((hn, he, pz), (0.0, 0.0, vz), (NAN, NAN, NAN), self._yaw)
        self._hold = (hn, he, hd)

    # ------------------------------------------------------------------ failsafe (supervise rate)
    def supervise(self) -> None:
        ap = self.ap
        c = ap.core
        if self.last_ns is None or self.lost or self.fresh():
            return
        self.lost = True
        ap.say(Severity.CRITICAL, "Manual control lost")
        if not c.armed or c.landed_state == LandedState.ON_GROUND:
            return
        act = int(ap.params["NAV_RCL_ACT"])
        exempt = int(ap.params["COM_RCL_EXCEPT"])
        mode = c.mode
        exempt_here = (
            (mode == FlightMode.MISSION and exempt & 1)
            or (mode == FlightMode.HOLD and exempt & 2)
            or (mode == FlightMode.OFFBOARD and exempt & 4)
        )
        if mode not in STICK_MODES and (act == 0 or exempt_here):
            return
        if act == 6:
            ap.cut_motors("Failsafe: manual control lost, disarming")
            return
        target = {2: FlightMode.RTL, 3: FlightMode.LAND, 5: FlightMode.LAND}.get(act, FlightMode.HOLD)
        if target == FlightMode.RTL and ap.home_ned is None:
            target = FlightMode.LAND
        if not c.est.pos_valid:
            target = FlightMode.LAND
        ap.failsafe = Failsafe.RC_LOSS
        ap.say(Severity.CRITICAL, f"Failsafe: manual control lost, {target.name}")
        ap.switch_mode(target)
