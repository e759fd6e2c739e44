"""Parameters with PX4 names: definitions (type, default, range, unit) and a thread-safe registry.

``FLOWN_DEFS`` are the parameters the flight core reads (their values, ranges and behaviour are the
harness's own, kept as they were before PX4's full table came in). ``PARAM_DEFS`` is every parameter of
PX4 (``harness.autopilot.params_data``, QGroundControl's metadata of PX4) plus those, sorted by name as PX4
lists them: the others are *accepted, not flown* — read, set (range-checked), saved and logged, and
nothing in the flight core changes with them.

The registry keeps a fixed order (the MAVLink parameter protocol addresses parameters by index), tells
subscribers about changes, and bumps ``version`` on every change so hot loops can re-read their gains
only when something changed.
"""

from __future__ import annotations

import enum
import math
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

from harness.autopilot.api import CommandResult
from harness.autopilot.params_data import load as px4_metadata
from harness.core.errors import ScenarioError
from harness.core.limits import shown


class ParamType(enum.IntEnum):
    """MAVLink MAV_PARAM_TYPE values PX4 uses."""

    INT32 = 6
    FLOAT = 9


@dataclass(frozen=True, slots=True)
class ParamDef:
    name: str
    type: ParamType
    default: float
    min: float
    max: float
    unit: str = ""
    description: str = ""
    flown: bool = True
    """False: PX4's parameter, accepted and stored; the flight core does not read it."""


def _f(name: str, default: float, lo: float, hi: float, unit: str = "", desc: str = "") -> ParamDef:
    return ParamDef(name, ParamType.FLOAT, float(default), lo, hi, unit, desc)


def _i(name: str, default: int, lo: int, hi: int, desc: str = "") -> ParamDef:
    return ParamDef(name, ParamType.INT32, default, lo, hi, "", desc)


_D = math.radians

FLOWN_DEFS: tuple[ParamDef, ...] = (
    # Attitude estimator (PX4 attitude_estimator_q names)
    _f("ATT_W_ACC", 0.3, 0.0, 1.0, "", "Complementary filter weight of the accelerometer"),
    _f("ATT_W_MAG", 0.3, 0.0, 1.0, "", "Complementary filter weight of the magnetometer"),
    _f("ATT_W_GYRO_BIAS", 0.1, 0.0, 1.0, "", "Gyro bias learning weight"),
    # Position estimator gains (PX4 has no equivalent for a complementary filter; EKF2_* noise names used)
    _f("EKF2_GPS_P_NOISE", 2.5, 0.01, 10.0, "m", "GPS position noise (sets the position fusion gain)"),
    _f("EKF2_GPS_V_NOISE", 0.3, 0.01, 5.0, "m/s", "GPS velocity noise (sets the velocity fusion gain)"),
    _f("EKF2_BARO_NOISE", 0.5, 0.01, 15.0, "m", "Barometer noise (sets the height fusion gain)"),
    _f("EKF2_MAG_DECL", 3.0, -180.0, 180.0, "deg", "Magnetic declination at the flying site"),
    _f("EKF2_GPS_DELAY", 0.0, 0.0, 300.0, "ms", "GPS measurement delay"),
    _i("EKF2_REQ_NSATS", 6, 4, 12, "Satellites required to use GPS"),
    _i("EKF2_NOAID_TOUT", 5000000, 500000, 10000000, "Dead reckoning without GPS this long (us), then no position"),
    _f("EKF2_REQ_EPH", 3.0, 2.0, 100.0, "m", "Horizontal accuracy required to use GPS"),
    # Multicopter attitude / rate control
    _f("MC_ROLL_P", 6.5, 0.0, 12.0, "1/s"),
    _f("MC_PITCH_P", 6.5, 0.0, 12.0, "1/s"),
    _f("MC_YAW_P", 2.8, 0.0, 5.0, "1/s"),
    _f("MC_YAW_WEIGHT", 0.4, 0.0, 1.0),
    _f("MC_ROLLRATE_P", 0.15, 0.01, 0.6),
    _f("MC_ROLLRATE_I", 0.2, 0.0, 10.0),
    _f("MC_ROLLRATE_D", 0.003, 0.0, 0.01),
    _f("MC_RR_INT_LIM", 0.3, 0.0, 1.0),
    _f("MC_PITCHRATE_P", 0.15, 0.01, 0.6),
    _f("MC_PITCHRATE_I", 0.2, 0.0, 10.0),
    _f("MC_PITCHRATE_D", 0.003, 0.0, 0.01),
    _f("MC_PR_INT_LIM", 0.3, 0.0, 1.0),
    _f("MC_YAWRATE_P", 0.2, 0.0, 0.6),
    _f("MC_YAWRATE_I", 0.1, 0.0, 10.0),
    _f("MC_YAWRATE_D", 0.0, 0.0, 0.01),
    _f("MC_YR_INT_LIM", 0.3, 0.0, 1.0),
    _f("MC_ROLLRATE_MAX", 220.0, 0.0, 1800.0, "deg/s"),
    _f("MC_PITCHRATE_MAX", 220.0, 0.0, 1800.0, "deg/s"),
    _f("MC_YAWRATE_MAX", 200.0, 0.0, 1800.0, "deg/s"),
    # Multicopter position control
    _f("MPC_XY_P", 0.95, 0.0, 2.0, "1/s"),
    _f("MPC_Z_P", 1.0, 0.0, 1.5, "1/s"),
    _f("MPC_XY_VEL_P_ACC", 1.8, 1.2, 5.0, "1/s"),
    _f("MPC_XY_VEL_I_ACC", 1.5, 0.0, 60.0, "1/s2"),
    _f("MPC_XY_VEL_D_ACC", 0.2, 0.1, 2.0),
    _f("MPC_Z_VEL_P_ACC", 4.0, 2.0, 15.0, "1/s"),
    _f("MPC_Z_VEL_I_ACC", 2.0, 0.2, 3.0, "1/s2"),
    _f("MPC_Z_VEL_D_ACC", 0.0, 0.0, 2.0),
    _f("MPC_XY_VEL_MAX", 12.0, 0.0, 20.0, "m/s"),
    _f("MPC_XY_CRUISE", 5.0, 3.0, 20.0, "m/s"),
    _f("MPC_Z_VEL_MAX_UP", 3.0, 0.5, 8.0, "m/s"),
    _f("MPC_Z_VEL_MAX_DN", 1.5, 0.5, 4.0, "m/s"),
    _f("MPC_ACC_HOR", 3.0, 2.0, 15.0, "m/s2"),
    _f("MPC_ACC_HOR_MAX", 5.0, 2.0, 15.0, "m/s2"),
    _f("MPC_ACC_UP_MAX", 4.0, 1.0, 15.0, "m/s2"),
    _f("MPC_ACC_DOWN_MAX", 3.0, 1.0, 15.0, "m/s2"),
    _f("MPC_TILTMAX_AIR", 45.0, 20.0, 89.0, "deg"),
    _f("MPC_TILTMAX_LND", 12.0, 10.0, 89.0, "deg"),
    _f("THR_MDL_FAC", 1.0, 0.0, 1.0, "", "Thrust model factor: thrust = f*u^2 + (1-f)*u"),
    _f("MPC_THR_HOVER", 0.52, 0.1, 0.8),
    _i("MPC_USE_HTE", 1, 0, 1, "Estimate the hover thrust in flight (starts from MPC_THR_HOVER)"),
    _f("MPC_THR_MIN", 0.08, 0.05, 0.5),
    _f("MPC_THR_MAX", 1.0, 0.0, 1.0),
    _f("MPC_LAND_SPEED", 0.7, 0.6, 4.0, "m/s"),
    _f("MPC_LAND_ALT1", 10.0, 0.0, 122.0, "m"),
    _f("MPC_LAND_ALT2", 5.0, 0.0, 122.0, "m"),
    _f("MPC_TKO_SPEED", 1.5, 1.0, 5.0, "m/s"),
    _f("MPC_YAWRAUTO_MAX", 45.0, 5.0, 360.0, "deg/s"),
    _f("MPC_XY_ERR_MAX", 2.0, 0.1, 10.0),
    _f("MPC_HOLD_MAX_XY", 0.8, 0.0, 3.0, "m/s"),
    # Manual control (sticks: harness.autopilot.manual)
    _f("MPC_HOLD_DZ", 0.1, 0.0, 1.0, "", "Stick deadzone (fraction of full deflection)"),
    _f("MPC_VEL_MANUAL", 10.0, 3.0, 20.0, "m/s", "Horizontal speed at full stick in position mode"),
    _f("MPC_MAN_TILT_MAX", 35.0, 0.0, 90.0, "deg", "Tilt at full stick in altitude and stabilized modes"),
    _f("MPC_MAN_Y_MAX", 150.0, 0.0, 400.0, "deg/s", "Yaw rate at full stick"),
    _f("MPC_MANTHR_MIN", 0.08, 0.0, 1.0, "", "Thrust at zero throttle stick in stabilized mode"),
    # Navigator / mission
    _f("MIS_TAKEOFF_ALT", 2.5, 0.0, 200.0, "m", "Default takeoff altitude above home"),
    _f("MIS_DIST_1WP", 900.0, 0.0, 10000.0, "m", "Refuse a mission whose first waypoint is further"),
    _i("MIS_YAW_ON", 0, 0, 1, "Yaw towards the next waypoint"),
    _f("NAV_ACC_RAD", 2.0, 0.05, 200.0, "m", "Horizontal acceptance radius"),
    _f("NAV_MC_ALT_RAD", 0.8, 0.05, 200.0, "m", "Vertical acceptance radius"),
    _i("NAV_DLL_ACT", 0, 0, 6, "Data link loss action (0 disabled)"),
    _i("NAV_RCL_ACT", 0, 0, 6, "RC loss action: 0 disabled, 1 hold, 2 return, 3 land, 5 terminate, 6 disarm"),
    _f("NAV_FT_DST", 8.0, 1.0, 50.0, "m"),
    _f("FLW_TGT_HT", 8.0, 8.0, 100.0, "m", "Follow-me height"),
    _f("FLW_TGT_DST", 8.0, 1.0, 50.0, "m", "Follow-me distance"),
    _f("FLW_TGT_FA", 180.0, -180.0, 180.0, "deg", "Follow-me angle from the target's course (0 in front)"),
    _f("FLW_TGT_RS", 0.1, 0.0, 1.0, "", "Follow-me responsiveness (target estimator smoothing)"),
    _i("FLW_TGT_ALT_M", 0, 0, 2, "Follow-me altitude mode: 0 constant, 1 terrain, 2 track the target's GPS altitude"),
    _f("FLW_TGT_MAX_VEL", 5.0, 0.0, 20.0, "m/s", "Follow-me maximum speed"),
    _f("RTL_RETURN_ALT", 30.0, 0.0, 150.0, "m", "Return altitude above home"),
    _f("RTL_DESCEND_ALT", 10.0, 2.0, 100.0, "m"),
    _f("RTL_LAND_DELAY", 0.0, -1.0, 300.0, "s"),
    _f("RTL_MIN_DIST", 5.0, 0.0, 100.0, "m", "Closer than this, return lands at once at the current altitude"),
    # Commander
    _i("COM_ARM_WO_GPS", 0, 0, 1, "Allow arming without a GPS fix"),
    _f("COM_DISARM_LAND", 2.0, -1.0, 20.0, "s", "Disarm this long after touchdown"),
    _f("COM_DISARM_PRFLT", 10.0, -1.0, 20.0, "s", "Disarm when armed and not taken off"),
    _i("COM_OBL_RC_ACT", 5, 0, 7, "Offboard loss action: 0 position, 3 return, 4 land, 5 hold"),
    _f("COM_OF_LOSS_T", 0.5, 0.0, 60.0, "s", "Offboard setpoint loss timeout (sim time)"),
    _i("COM_LOW_BAT_ACT", 3, 0, 3, "Low battery action: 0 warn, 2 land, 3 return then land at critical"),
    _i("COM_RC_IN_MODE", 1, 0, 4, "Manual input: 1 MAVLink MANUAL_CONTROL (joystick), 4 ignored (no RC)"),
    _f("COM_RC_LOSS_T", 0.5, 0.0, 35.0, "s", "RC loss timeout (sim time since the last MANUAL_CONTROL)"),
    _i("COM_RCL_EXCEPT", 0, 0, 31, "Modes without RC loss failsafe: bit 0 mission, 1 hold, 2 offboard"),
    _i("COM_POSCTL_NAVL", 0, 0, 1, "Position mode on navigation loss: 0 altitude mode, 1 land (descend)"),
    _i("COM_PREARM_MODE", 1, 0, 2),
    # Geofence
    _i("GF_ACTION", 3, 0, 5, "Geofence breach action: 0 none, 1 warn, 2 hold, 3 return, 5 land"),
    _f("GF_MAX_HOR_DIST", 0.0, 0.0, 10000.0, "m", "Max horizontal distance from home (0 disabled)"),
    _f("GF_MAX_VER_DIST", 0.0, 0.0, 10000.0, "m", "Max height above home (0 disabled)"),
    _i("GF_SOURCE", 0, 0, 1),
    # Battery
    _i("BAT_N_CELLS", 4, 1, 14),
    _f("BAT_CAPACITY", 5000.0, 0.0, 100000.0, "mAh"),
    _f("BAT_V_CHARGED", 4.2, 3.0, 5.0, "V", "Cell voltage when full"),
    _f("BAT_V_EMPTY", 3.5, 2.5, 4.0, "V", "Cell voltage when empty"),
    _f("BAT_R_INTERNAL", 0.02, 0.0, 0.5, "Ohm", "Pack internal resistance (voltage sag)"),
    _f("BAT_LOW_THR", 0.15, 0.12, 0.5, "", "Low battery: return"),
    _f("BAT_CRIT_THR", 0.07, 0.05, 0.25, "", "Critical battery: land"),
    _f("BAT_EMERGEN_THR", 0.05, 0.03, 0.1),
    _f("SIM_BAT_DRAIN", 1.0, 0.0, 1000.0, "", "Battery drain multiplier (tests speed up the drain)"),
    _f("SIM_MOT_POWER", 120.0, 1.0, 5000.0, "W", "Electrical power of one motor at full command"),
    # The simulated world, ArduPilot SITL's names and units (harness/autopilot/simworld.py; docs/ardupilot.md)
    _f("SIM_WIND_SPD", 0.0, 0.0, 100.0, "m/s", "Simulated wind speed"),
    _f("SIM_WIND_DIR", 180.0, -360.0, 360.0, "deg", "Direction the simulated wind comes from (true)"),
    _f("SIM_WIND_DIR_Z", 0.0, -90.0, 90.0, "deg", "Vertical direction of the wind: 0 horizontal, 90 updraft"),
    _f("SIM_WIND_TURB", 0.0, 0.0, 30.0, "m/s", "Simulated wind variation (gust standard deviation)"),
    _i("SIM_GPS_DISABLE", 0, 0, 1, "1: the GPS sends nothing"),
    _f("SIM_GPS_GLITCH_X", 0.0, -1.0, 1.0, "deg", "GPS latitude glitch"),
    _f("SIM_GPS_GLITCH_Y", 0.0, -1.0, 1.0, "deg", "GPS longitude glitch"),
    _f("SIM_GPS_GLITCH_Z", 0.0, -1000.0, 1000.0, "m", "GPS altitude glitch"),
    _i("SIM_BARO_DISABLE", 0, 0, 1, "1: the barometer sends nothing"),
    _f("SIM_BARO_GLITCH", 0.0, -1000.0, 1000.0, "m", "Barometer altitude glitch"),
    _i("SIM_MAG1_FAIL", 0, 0, 1, "1: the compass sends nothing"),
    _f("SIM_BATT_VOLTAGE", 16.8, 0.0, 100.0, "V", "Resting voltage: the battery's charge (clipped to full)"),
    _i("SIM_ENGINE_FAIL", 0, 0, 15, "Motors (bit 0 = motor 1) whose thrust SIM_ENGINE_MUL scales"),
    _f("SIM_ENGINE_MUL", 0.0, 0.0, 1.0, "", "Thrust multiplier of the motors in SIM_ENGINE_FAIL"),
    _f("SIM_SPEEDUP", 0.0, 0.0, 1e6, "", "The run's pace: times real time, 0 as fast as possible"),
    # System
    _i("SYS_AUTOSTART", 4001, 0, 9999999),
    _i("SYS_FAILURE_EN", 0, 0, 1, "Enable failure injection"),
    _i("SYS_HITL", 0, -1, 2),
    _i("MAV_SYS_ID", 1, 1, 250),
    _i("MAV_COMP_ID", 1, 1, 250),
    _i("MAV_TYPE", 2, 0, 22),
    _i("CBRK_SUPPLY_CHK", 0, 0, 894281),
)

ACCEPTED_NOT_FLOWN = "accepted, not flown"
CALIBRATION_RESULT = "calibration result (accepted, not flown)"
SITL_ACCEL_ID, SITL_GYRO_ID, SITL_MAG_ID = 1310988, 1310988, 197388
"""PX4 SITL's simulated sensors' device ids (what its calibration stores in CAL_*0_ID)."""


def _calibration_defs() -> tuple[ParamDef, ...]:
    """PX4's per-instance calibration parameters of the first accelerometer, gyro and magnetometer: generated
    by the firmware from templates, so absent from QGroundControl's metadata. The calibration service
    (``mavlink/calibration.py``) writes them; the flight core does not read them."""
    defs = []
    for sensor, scaled in (("ACC", True), ("GYRO", False), ("MAG", True)):
        defs.append(ParamDef(f"CAL_{sensor}0_ID", ParamType.INT32, 0, 0, 2139095040, "", CALIBRATION_RESULT, False))
        defs.append(ParamDef(f"CAL_{sensor}0_PRIO", ParamType.INT32, -1, -1, 100, "", CALIBRATION_RESULT, False))
        for axis in "XYZ":
            defs.append(
                ParamDef(f"CAL_{sensor}0_{axis}OFF", ParamType.FLOAT, 0.0, -1e3, 1e3, "", CALIBRATION_RESULT, False)
            )
            if scaled:
                defs.append(
                    ParamDef(
                        f"CAL_{sensor}0_{axis}SCALE", ParamType.FLOAT, 1.0, 0.1, 3.0, "", CALIBRATION_RESULT, False
                    )
                )
    return tuple(defs)


def _all_defs() -> tuple[ParamDef, ...]:
    flown = {d.name: d for d in FLOWN_DEFS}
    others = {
        m.name: ParamDef(
            m.name,
            ParamType.INT32 if m.is_int else ParamType.FLOAT,
            m.default,
            m.min,
            m.max,
            m.unit,
            ACCEPTED_NOT_FLOWN,
            flown=False,
        )
        for m in px4_metadata().params
        if m.name not in flown
    }
    for d in _calibration_defs():
        others.setdefault(d.name, d)
    return tuple(sorted((*FLOWN_DEFS, *others.values()), key=lambda d: d.name))


PARAM_DEFS: tuple[ParamDef, ...] = _all_defs()
"""Every parameter of a PX4 vehicle, sorted by name."""


class Params:
    """A thread-safe ordered parameter registry."""

    def __init__(self, defs: Iterable[ParamDef] = PARAM_DEFS, overrides: Mapping[str, float] | None = None) -> None:
        self._defs = tuple(defs)
        self._index = {d.name: i for i, d in enumerate(self._defs)}
        if len(self._index) != len(self._defs):
            raise ScenarioError("duplicate parameter names in the definitions")
        self._values: dict[str, float] = {d.name: d.default for d in self._defs}
        self._lock = threading.Lock()
        self._subscribers: list[Callable[[str, float], None]] = []
        self.version = 0
        """Bumped on every change (hot loops compare it to re-read cached values)."""
        self.overrides: dict[str, float] = dict(overrides or {})
        """The values given over the defaults at creation (the scenario's): what a reboot starts from again."""
        for name, value in self.overrides.items():
            result = self.set(name, value)
            if not result.ok:
                raise ScenarioError(f"parameter override {name}={value}: {result.reason}")

    def __len__(self) -> int:
        return len(self._defs)

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    @property
    def defs(self) -> tuple[ParamDef, ...]:
        return self._defs

    def names(self) -> list[str]:
        return [d.name for d in self._defs]

    def index(self, name: str) -> int:
        """Index in the ordered list; -1 when unknown."""
        return self._index.get(name, -1)

    def definition(self, name_or_index: str | int) -> ParamDef | None:
        if isinstance(name_or_index, int):
            return self._defs[name_or_index] if 0 <= name_or_index < len(self._defs) else None
        i = self._index.get(name_or_index)
        return None if i is None else self._defs[i]

    def get(self, name: str) -> float | int:
        """The value, as int for INT32 parameters. Raises ``KeyError`` for an unknown name."""
        d = self._defs[self._index[name]]
        v = self._values[name]
        return int(v) if d.type == ParamType.INT32 else v

    def set(self, name: str, value: float) -> CommandResult:
        """Set a value; refuses unknown names, NaN/inf, non-integers for INT32 and values out of range."""
        i = self._index.get(name)
        if i is None:
            return CommandResult.denied(f"unknown parameter {shown(name)}")
        d = self._defs[i]
        try:
            v = float(value)
        except (OverflowError, TypeError, ValueError):
            v = math.nan
        if not math.isfinite(v):
            return CommandResult.denied(f"{name}: value {shown(value)} is not finite")
        if d.type == ParamType.INT32 and v != int(v):
            return CommandResult.denied(f"{name} is an integer parameter, got {value}")
        if not d.min <= v <= d.max:
            return CommandResult.denied(f"{name}={value} outside [{d.min:g}, {d.max:g}]")
        with self._lock:
            changed = self._values[name] != v
            self._values[name] = v
            if changed:
                self.version += 1
            subs = list(self._subscribers)
        if changed:
            for cb in subs:
                cb(name, v)
        return CommandResult.accepted()

    def subscribe(self, callback: Callable[[str, float], None]) -> None:
        """Call ``callback(name, value)`` after every change (from the thread that made it)."""
        with self._lock:
            self._subscribers.append(callback)

    def snapshot(self) -> dict[str, float]:
        """All values by name (INT32 values as ints), in order."""
        with self._lock:
            vals = dict(self._values)
        return {d.name: (int(vals[d.name]) if d.type == ParamType.INT32 else vals[d.name]) for d in self._defs}

    def update(self, values: Mapping[str, float]) -> list[str]:
        """Set many (e.g. restored from storage); returns the reasons of those refused."""
        return [r.reason for n, v in values.items() if not (r := self.set(n, v)).ok]


def deg(params: Params, name: str) -> float:
    """A parameter given in degrees, in radians."""
    return _D(params[name])
