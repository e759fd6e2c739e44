"""The per-tick flight core: estimator → navigator → control cascade → mixer, plus the land detector.

``FlightCore`` holds no lock and knows nothing of threads or MAVLink; ``Autopilot`` (``autopilot.py``)
wraps it with the command API, arming checks and failsafes.
"""

from __future__ import annotations

import math

from harness.autopilot.api import FlightMode, LandedState
from harness.autopilot.battery import Battery
from harness.autopilot.control import PositionControl, thrust_attitude
from harness.autopilot.estimator import Estimator
from harness.autopilot.geofence import Geofence
from harness.autopilot.inner import AttitudeControl, RateControl, inner_loop
from harness.autopilot.mathutil import G_M_S2
from harness.autopilot.navigator import Navigator
from harness.autopilot.params import Params
from harness.core.geo import GeoRef
from harness.core.jit import compiled
from harness.fdm.frame import SensorFrame

_isnan = math.isnan
ZERO4 = (0.0, 0.0, 0.0, 0.0)
ZERO3 = (0.0, 0.0, 0.0)
_inner_loop = compiled(inner_loop)
_thrust_attitude = compiled(thrust_attitude)


class FlightCore:
    def __init__(self, params: Params, use_ground_truth: bool = False, origin: GeoRef | None = None) -> None:
        self.params = params
        self.texts: list[tuple[int, str]] = []
        self.est = Estimator(params, use_ground_truth, origin)
        self.nav = Navigator(params, self.est, self._text)
        self.pos_ctl = PositionControl(params)
        self.att_ctl = AttitudeControl(params)
        self.rate_ctl = RateControl(params)
        self.battery = Battery(params)
        self.fence = Geofence(params)
        self.armed = False
        self.mode = FlightMode.HOLD
        self.landed_state = LandedState.ON_GROUND
        self.motors: tuple[float, float, float, float] = ZERO4
        self.collective = 0.0
        self.t_ns = -1
        self.ground_pd = 0.0
        self.yaw_hold = 0.0
        self._contact_s = 0.0
        self._landed_s = 0.0
        self._bat_dt = 0.0
        self.pos_every = 2
        """Navigator and position control run every ``pos_every`` ticks (125 Hz at a 250 Hz tick)."""
        self._pos_n = 0
        self._pos_dt = 0.0
        self._qd: tuple[float, float, float, float] | None = None
        self._coll = 0.0
        self._yaw_ff = 0.0
        self._ver = -1
        self._hover_param = -1.0
        self._load()

    def _text(self, severity: int, text: str) -> None:
        self.texts.append((severity, text))

    def _load(self) -> None:
        p = self.params
        self._ver = p.version
        self.att_ctl.refresh()
        self.rate_ctl.refresh()
        self._idle = p["MPC_THR_MIN"] * 0.5
        if p["MPC_THR_HOVER"] != self._hover_param:
            self._hover_param = p["MPC_THR_HOVER"]
            self.hover_thrust = self._hover = self.pos_ctl.hover = self._hover_param
        self._hte = bool(p["MPC_USE_HTE"])
        self._fac = p["THR_MDL_FAC"]

    def step(self, frame: SensorFrame) -> tuple[float, float, float, float]:
        if self.params.version != self._ver:
            self._load()
        dt = (frame.t_ns - self.t_ns) * 1e-9 if self.t_ns >= 0 else 0.004
        if not 0.0 < dt <= 0.05:
            dt = 0.004 if dt <= 0.0 else 0.05
        self.t_ns = frame.t_ns
        self.est.update(frame, dt)
        self._bat_dt += dt
        if self._bat_dt >= 0.04:
            self.battery.update(self.motors, self.armed, self._bat_dt)
            self._bat_dt = 0.0
        motors = self._control(dt)
        self._land_detector(dt)
        self.motors = motors
        return motors

    def _reset_controllers(self) -> None:
        self.pos_ctl.reset()
        self.rate_ctl.reset()
        self.yaw_hold = self.est.yaw
        self.nav.yaw_sp = self.yaw_hold

    def _control(self, dt: float) -> tuple[float, float, float, float]:
        est = self.est
        nav = self.nav
        if not self.armed or not est.att_valid:
            self._reset_controllers()
            self.collective = 0.0
            return ZERO4
        on_ground = self.landed_state == LandedState.ON_GROUND
        att = nav.offboard_att if self.mode == FlightMode.OFFBOARD else nav.manual_att
        if att is not None:
            if on_ground and att.thrust < self._hover * 0.6:
                return self._idle_out()
            # attitude P on the quaternion when there is one, the body rates added (or alone)
            br = att.body_rates_rad_s
            return self._inner(
                att.quat or est.q, att.quat is not None, 0.0, br or ZERO3, br is not None, att.thrust, dt
            )
        self._pos_dt += dt
        self._pos_n += 1
        if self._pos_n >= self.pos_every or on_ground or self._qd is None:
            # outer loop (navigator + position control) at tick rate / pos_every
            pdt = self._pos_dt
            self._pos_n = 0
            self._pos_dt = 0.0
            sp = nav.update(pdt, on_ground)
            if on_ground and not self.climb_requested(sp):
                self._qd = None
                return self._idle_out()
            if on_ground:
                # leaving the ground: no horizontal integrator from the time on the ground
                self.pos_ctl.ix = self.pos_ctl.iy = 0.0
            if self._hte and self.landed_state == LandedState.IN_AIR:
                self._estimate_hover(pdt)
            thr = self.pos_ctl.update(sp, (est.pn, est.pe, est.pd), (est.vn, est.ve, est.vd), pdt)
            self._yaw_ff = 0.0
            if not _isnan(sp.yaw):
                self.yaw_hold = sp.yaw
            if not _isnan(sp.yaw_rate):
                self._yaw_ff = sp.yaw_rate
                if _isnan(sp.yaw):
                    self.yaw_hold = math.remainder(self.yaw_hold + sp.yaw_rate * pdt, 2.0 * math.pi)
            qw, qx, qy, qz, self._coll = _thrust_attitude(thr[0], thr[1], thr[2], self.yaw_hold)
            self._qd = (qw, qx, qy, qz)
        return self._inner(self._qd, True, self._yaw_ff, ZERO3, False, self._coll, dt)

    def _estimate_hover(self, dt: float) -> None:
        """Hover thrust from the thrust applied and the vertical acceleration it gave (PX4's MPC_USE_HTE)."""
        tz = self.pos_ctl.thr[2]
        denom = G_M_S2 - self.est.acc_d
        if tz >= -0.05 or denom < 3.0:
            return
        h = -tz * G_M_S2 / denom
        hov = self.hover_thrust + (dt / 3.0) * (h - self.hover_thrust)
        hov = 0.1 if hov < 0.1 else (0.9 if hov > 0.9 else hov)
        self.hover_thrust = hov
        self.pos_ctl.set_hover(hov)
        self._hover = hov

    def climb_requested(self, sp: object) -> bool:
        nav = self.nav
        if nav.wants_climb:
            return True
        if self.mode != FlightMode.OFFBOARD:
            return False
        s = nav.sp
        est = self.est
        return (
            (not _isnan(s.vz) and s.vz < -0.3)
            or (not _isnan(s.pz) and s.pz < est.pd - 0.3)
            or (not _isnan(s.az) and s.az < -1.0)
        )

    def _idle_out(self) -> tuple[float, float, float, float]:
        self._reset_controllers()
        nav = self.nav
        nav.tr.reset((self.est.pn, self.est.pe, self.est.pd))
        self.collective = self._idle
        i = self._idle
        return (i, i, i, i)

    def _inner(
        self,
        qd: tuple[float, float, float, float],
        use_att: bool,
        yaw_ff: float,
        body_rates: tuple[float, float, float],
        add_rates: bool,
        thrust: float,
        dt: float,
    ) -> tuple[float, float, float, float]:
        """The per-tick cascade (``inner.inner_loop``): attitude setpoint ``qd`` (if ``use_att``) and/or body
        rates → rate PID → mixer → thrust model, in one compiled call."""
        att, rate, est = self.att_ctl, self.rate_ctl, self.est  # (their gains refreshed by _load)
        self.collective = thrust
        return _inner_loop(
            att.gains, rate.gains, rate.state, use_att, *est.q, *qd, yaw_ff, add_rates, *body_rates, *est.rates,
            thrust, dt, self.landed_state != LandedState.ON_GROUND, self._idle, self._fac,
        )  # fmt: skip

    def _land_detector(self, dt: float) -> None:
        est = self.est
        ls = self.landed_state
        if not self.armed:
            self.landed_state = LandedState.ON_GROUND
            self.ground_pd = est.pd
            self._contact_s = 0.0
            return
        if ls == LandedState.ON_GROUND:
            self._landed_s += dt
            if self.collective > self._hover * 0.6 and (self.nav.wants_climb or self.mode == FlightMode.OFFBOARD):
                self.landed_state = LandedState.TAKEOFF
                self._landed_s = 0.0
            return
        height = self.ground_pd - est.pd
        if ls == LandedState.TAKEOFF:
            if height > 1.0 or (self.mode == FlightMode.OFFBOARD and height > 0.5):
                self.landed_state = LandedState.IN_AIR
            elif self.collective < self._hover * 0.3 and height < 0.2:
                self.landed_state = LandedState.ON_GROUND
            return
        # in air or landing: ground contact = wants down, not moving, thrust well below hover
        landing = self.nav.landing
        self.landed_state = LandedState.LANDING if landing else LandedState.IN_AIR
        wants_down = landing or (self.mode == FlightMode.OFFBOARD and self.pos_ctl.vel_sp[2] > 0.2)
        contact = (
            wants_down
            and abs(est.vd) < 0.3
            and (not est.pos_valid or math.hypot(est.vn, est.ve) < 1.0)  # (no GPS: PX4 skips the check)
            and self.collective < self._hover * 0.85
        )
        self._contact_s = self._contact_s + dt if contact else 0.0
        if self._contact_s > 1.0:
            self.landed_state = LandedState.ON_GROUND
            self.ground_pd = est.pd
            self._contact_s = 0.0
            self._landed_s = 0.0
            self._text(6, "Landing detected")
