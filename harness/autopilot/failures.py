"""Failure injection as PX4 does it (MAV_CMD_INJECT_FAILURE, gated by ``SYS_FAILURE_EN``), and the
navigation-loss failsafe that a lost GPS leads to.

A failure is a (unit, type, instance) triple of MAVLink's FAILURE_UNIT / FAILURE_TYPE; instance 0 means
every instance. Sensor failures act on the sensor frame before the estimator sees it (as PX4's simulated
sensor drivers stop publishing or repeat their last sample); a motor failure zeroes that motor's command
after the mixer, so the FDM really flies on three motors; a battery failure empties the battery.

What the estimator and commander then do is the ordinary flight core reacting to missing data, plus
:meth:`FailureInjector.supervise`: without GPS the position estimate dead-reckons for ``EKF2_NOAID_TOUT``
and is then invalid (PX4's EKF2); a mode that needs a position then falls back as PX4's failsafe state
machine does — position mode to altitude mode (``COM_POSCTL_NAVL`` 0, with sticks) and everything else
to Land, which without a position is PX4's Descend (level, straight down at the land speed).
"""

from __future__ import annotations

import enum
from typing import Protocol

import msgspec

from harness.autopilot.api import CommandResult, Failsafe, FlightMode, LandedState, Severity
from harness.autopilot.supervisor import Commander
from harness.fdm.frame import MOTOR_COUNT, Imu, SensorFrame


class _Config(Protocol):
    @property
    def use_ground_truth(self) -> bool: ...


class FailureHost(Commander, Protocol):
    """What the failure injector reads of, and does to, its autopilot (``harness.autopilot.Autopilot``)."""

    @property
    def config(self) -> _Config: ...


class FailureUnit(enum.IntEnum):
    """MAVLink FAILURE_UNIT."""

    SENSOR_GYRO = 0
    SENSOR_ACCEL = 1
    SENSOR_MAG = 2
    SENSOR_BARO = 3
    SENSOR_GPS = 4
    SENSOR_OPTICAL_FLOW = 5
    SENSOR_VIO = 6
    SENSOR_DISTANCE_SENSOR = 7
    SENSOR_AIRSPEED = 8
    SYSTEM_BATTERY = 100
    SYSTEM_MOTOR = 101
    SYSTEM_SERVO = 102
    SYSTEM_AVOIDANCE = 103
    SYSTEM_RC_SIGNAL = 104
    SYSTEM_MAVLINK_SIGNAL = 105


class FailureType(enum.IntEnum):
    """MAVLink FAILURE_TYPE."""

    OK = 0
    OFF = 1
    STUCK = 2
    GARBAGE = 3
    WRONG = 4
    SLOW = 5
    DELAYED = 6
    INTERMITTENT = 7


_SENSORS = frozenset(
    {
        FailureUnit.SENSOR_GYRO,
        FailureUnit.SENSOR_ACCEL,
        FailureUnit.SENSOR_MAG,
        FailureUnit.SENSOR_BARO,
        FailureUnit.SENSOR_GPS,
    }
)
SUPPORTED: dict[FailureUnit, frozenset[FailureType]] = {
    **{u: frozenset({FailureType.OK, FailureType.OFF, FailureType.STUCK}) for u in _SENSORS},
    FailureUnit.SYSTEM_MOTOR: frozenset({FailureType.OK, FailureType.OFF}),
    FailureUnit.SYSTEM_BATTERY: frozenset({FailureType.OK, FailureType.OFF}),
    FailureUnit.SYSTEM_RC_SIGNAL: frozenset({FailureType.OK, FailureType.OFF}),
}
"""Every (unit, type) this autopilot simulates; anything else is answered UNSUPPORTED (as PX4 does)."""

_NEEDS_POSITION = frozenset(
    {
        FlightMode.HOLD,
        FlightMode.POSCTL,
        FlightMode.TAKEOFF,
        FlightMode.MISSION,
        FlightMode.RTL,
        FlightMode.ORBIT,
        FlightMode.FOLLOW_TARGET,
        FlightMode.OFFBOARD,
    }
)


class FailureInjector:
    """The injected failures of one vehicle: the autopilot's ``failure`` service. ``inject`` takes the autopilot's
    lock; the rest is called by ``Autopilot.step`` under it."""

    def __init__(self, ap: FailureHost) -> None:
        self.ap = ap
        self.active: dict[FailureUnit, FailureType] = {}
        self.motors_off: set[int] = set()
        """0-based indices of motors that are off."""
        self._last: dict[FailureUnit, object] = {}
        self.last_mag_gauss: tuple[float, float, float] | None = None
        """The last magnetometer sample the estimator got (HIGHRES_IMU reports it)."""
        self.last_baro_pa: float | None = None
        self.rc_off = False

    # ------------------------------------------------------------------ command
    def inject(self, unit: int, kind: int, instance: int) -> CommandResult:
        """MAV_CMD_INJECT_FAILURE (the MAVLink side checks ``SYS_FAILURE_EN``)."""
        with self.ap.lock:
            return self._inject(unit, kind, instance)

    def _inject(self, unit: int, kind: int, instance: int) -> CommandResult:
        try:
            u, k = FailureUnit(unit), FailureType(kind)
        except ValueError:
            return CommandResult.denied(f"Failure injection: unknown unit {unit} or type {kind}")
        if k not in SUPPORTED.get(u, frozenset()):
            return CommandResult.unsupported(f"Failure injection: {u.name} {k.name} is not simulated")
        if u == FailureUnit.SYSTEM_MOTOR:
            if not 0 <= instance <= MOTOR_COUNT:
                return CommandResult.denied(f"Failure injection: no motor {instance} (1..{MOTOR_COUNT}, 0 = all)")
            which = range(MOTOR_COUNT) if instance == 0 else (instance - 1,)
            if k == FailureType.OFF:
                self.motors_off.update(which)
            else:
                self.motors_off.difference_update(which)
            self._say(f"Failure injected: motor {instance or 'all'} {k.name.lower()}")
            return CommandResult.accepted()
        if k == FailureType.OK:
            self.active.pop(u, None)
            self._last.pop(u, None)
        else:
            self.active[u] = k
        if u == FailureUnit.SYSTEM_BATTERY and k == FailureType.OFF:
            bat = self.ap.core.battery
            bat.consumed_mah = max(bat.consumed_mah, self.ap.params["BAT_CAPACITY"])
        self.rc_off = self.active.get(FailureUnit.SYSTEM_RC_SIGNAL) == FailureType.OFF
        self.ap.state_changed()
        self._say(f"Failure injected: {u.name.lower()} {k.name.lower()}")
        return CommandResult.accepted()

    def _say(self, text: str) -> None:
        self.ap.say(Severity.WARNING, text)

    def off(self, unit: FailureUnit) -> bool:
        return self.active.get(unit) == FailureType.OFF

    # ------------------------------------------------------------------ per tick
    def sensors(self, frame: SensorFrame) -> SensorFrame:
        """The frame as the estimator gets it with the active failures (no copy when there is none)."""
        if self.active:
            frame = self._apply(frame)
        if frame.mag is not None:
            self.last_mag_gauss = frame.mag.field_body_gauss
        if frame.baro is not None:
            self.last_baro_pa = frame.baro.pressure_pa
        return frame

    def _apply(self, frame: SensorFrame) -> SensorFrame:
        fields: dict[str, object] = {}
        for unit, name in (
            (FailureUnit.SENSOR_GPS, "gps"),
            (FailureUnit.SENSOR_MAG, "mag"),
            (FailureUnit.SENSOR_BARO, "baro"),
        ):
            kind = self.active.get(unit)
            if kind is None:
                continue
            sample = getattr(frame, name)
            if kind == FailureType.OFF:
                fields[name] = None
            elif sample is not None:  # stuck: the first sample after the failure, repeated at the sensor's rate
                stuck = self._last.setdefault(unit, sample)
                if unit == FailureUnit.SENSOR_GPS:
                    stuck = msgspec.structs.replace(stuck, measured_at_ns=sample.measured_at_ns)  # type: ignore[type-var]
                fields[name] = stuck
        gyro, accel = self.active.get(FailureUnit.SENSOR_GYRO), self.active.get(FailureUnit.SENSOR_ACCEL)
        if gyro is not None or accel is not None:
            # a dead IMU driver: the estimator keeps its last sample (OFF and STUCK alike; OFF is also unhealthy)
            held = self._last.setdefault(FailureUnit.SENSOR_GYRO, frame.imu)
            assert isinstance(held, Imu)
            fields["imu"] = Imu(
                held.accel_body_m_s2 if accel is not None else frame.imu.accel_body_m_s2,
                held.gyro_body_rad_s if gyro is not None else frame.imu.gyro_body_rad_s,
                frame.imu.temperature_c,
            )
        if not fields:
            return frame
        return msgspec.structs.replace(frame, **fields)

    def motors(self, motors: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        if not self.motors_off:
            return motors
        m = list(motors)
        for i in self.motors_off:
            m[i] = 0.0
        return (m[0], m[1], m[2], m[3])

    # ------------------------------------------------------------------ commander
    def supervise(self) -> None:
        """Position validity after GPS loss (EKF2_NOAID_TOUT) and the navigation-loss failsafe."""
        ap = self.ap
        c = ap.core
        e = c.est
        timeout_ns = int(ap.params["EKF2_NOAID_TOUT"]) * 1000
        if c.t_ns - e.last_gps_ns > 500_000_000:
            e.forget_gps_motion()
        if e.pos_valid and not ap.config.use_ground_truth and c.t_ns - e.last_gps_ns > timeout_ns:
            e.pos_valid = False
            ap.say(Severity.CRITICAL, "No GPS: position estimate invalid")
        if e.pos_valid or not c.armed or c.landed_state == LandedState.ON_GROUND:
            return
        if c.mode not in _NEEDS_POSITION or (c.mode == FlightMode.OFFBOARD and ap.offboard.flies_attitude()):
            return  # (offboard attitude setpoints need no position)
        if c.mode == FlightMode.POSCTL and ap.params["COM_POSCTL_NAVL"] == 0 and ap.manual_control.fresh():
            target = FlightMode.ALTCTL
        else:
            target = FlightMode.LAND  # without a position: PX4's Descend
        ap.failsafe = Failsafe.NAVIGATION
        ap.say(Severity.CRITICAL, f"Failsafe: no position estimate, {target.name}")
        ap.switch_mode(target)
