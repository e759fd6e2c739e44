"""ArduCopter parameter names over the flight core's (PX4-named) parameters.

Each ArduCopter parameter is either *mapped* to a core parameter with ArduPilot's unit (``RTL_ALT`` in cm is
``RTL_RETURN_ALT`` in m x 100: setting one sets the other, and a core change shows up under the ArduPilot
name) or *own* to the personality (stream rates ``SRx_*``, ``SYSID_THISMAV``, ``FRAME_CLASS``, ...). The
fence parameters are combined: ``FENCE_ENABLE`` = 0 turns the core's fence limits off, 1 applies
``FENCE_RADIUS`` / ``FENCE_ALT_MAX`` (when ``FENCE_TYPE`` enables them) and ``FENCE_ACTION``.

:class:`CopterParams` is a :class:`~harness.autopilot.params.Params` registry with the ArduCopter names
(the parameter protocol serves it as is) kept in step with the core registry both ways.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from harness.autopilot.api import CommandResult
from harness.autopilot.param_table import ParamTable, parse_param_table
from harness.autopilot.params import FLOWN_DEFS, ParamDef, Params, ParamType
from harness.autopilot.params_data import copter_text
from harness.autopilot.simworld import NAMES as SIM_NAMES

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Mapped:
    """ArduPilot ``name`` = core ``core`` x ``scale``.

    ``ap_range`` is ArduCopter's documented range where it reaches beyond the core's: a value in it is accepted
    and stored as given (a read returns it, as ArduCopter's would) and the core gets the nearest value it
    takes (``THR_MIN`` = 10, i.e. 1 %, flies with ``MPC_THR_MIN`` = 0.05). Without one, the core's range
    in ArduPilot units is the range.
    """

    name: str
    core: str
    scale: float
    type: ParamType = ParamType.FLOAT
    unit: str = ""
    ap_range: tuple[float, float] | None = None


MAPPED: tuple[Mapped, ...] = (
    Mapped("WPNAV_SPEED", "MPC_XY_CRUISE", 100.0, unit="cm/s", ap_range=(10.0, 2000.0)),
    Mapped("WPNAV_SPEED_UP", "MPC_Z_VEL_MAX_UP", 100.0, unit="cm/s", ap_range=(10.0, 1000.0)),
    Mapped("WPNAV_SPEED_DN", "MPC_Z_VEL_MAX_DN", 100.0, unit="cm/s", ap_range=(10.0, 500.0)),
    Mapped("WPNAV_ACCEL", "MPC_ACC_HOR", 100.0, unit="cm/s/s", ap_range=(50.0, 500.0)),
    Mapped("WPNAV_RADIUS", "NAV_ACC_RAD", 100.0, unit="cm"),
    Mapped("LAND_SPEED", "MPC_LAND_SPEED", 100.0, unit="cm/s", ap_range=(30.0, 200.0)),
    Mapped("RTL_ALT", "RTL_RETURN_ALT", 100.0, unit="cm", ap_range=(30.0, 300000.0)),
    Mapped("RTL_LOIT_TIME", "RTL_LAND_DELAY", 1000.0, unit="ms"),
    Mapped("DISARM_DELAY", "COM_DISARM_PRFLT", 1.0, ParamType.INT32, "s", ap_range=(0.0, 127.0)),
    Mapped("GUID_TIMEOUT", "COM_OF_LOSS_T", 1.0, unit="s"),
    Mapped("ANGLE_MAX", "MPC_TILTMAX_AIR", 100.0, unit="cdeg", ap_range=(1000.0, 8000.0)),
    Mapped("BATT_CAPACITY", "BAT_CAPACITY", 1.0, ParamType.INT32, "mAh"),
    Mapped("MOT_THST_HOVER", "MPC_THR_HOVER", 1.0),
    # ArduCopter 3.x name (DroneKit's vehicle_state.py reads it and writes 10): 0-300 in 0.1 % of throttle
    Mapped("THR_MIN", "MPC_THR_MIN", 1000.0, unit="0.1 %", ap_range=(0.0, 300.0)),
    Mapped("THR_MID", "MPC_THR_HOVER", 1000.0, unit="0.1 %", ap_range=(300.0, 700.0)),  # 3.x: MOT_THST_HOVER
    Mapped("PSC_POSXY_P", "MPC_XY_P", 1.0),
    Mapped("PSC_POSZ_P", "MPC_Z_P", 1.0),
    Mapped("ATC_ANG_RLL_P", "MC_ROLL_P", 1.0),
    Mapped("ATC_ANG_PIT_P", "MC_PITCH_P", 1.0),
    Mapped("ATC_ANG_YAW_P", "MC_YAW_P", 1.0),
    Mapped("ATC_RAT_RLL_P", "MC_ROLLRATE_P", 1.0),
    Mapped("ATC_RAT_PIT_P", "MC_PITCHRATE_P", 1.0),
    Mapped("ATC_RAT_YAW_P", "MC_YAWRATE_P", 1.0),
    # ArduPilot SITL's simulated world: the core's own SIM_* under the same names (harness/autopilot/simworld.py)
    *(Mapped(d.name, d.name, 1.0, d.type, d.unit) for d in FLOWN_DEFS if d.name in SIM_NAMES),
)

CORE_DEFAULTS: dict[str, float] = {
    "RTL_RETURN_ALT": 15.0,  # RTL_ALT 1500 cm
    "RTL_LAND_DELAY": 5.0,  # RTL_LOIT_TIME 5000 ms
    "COM_OF_LOSS_T": 3.0,  # GUID_TIMEOUT 3 s: a velocity target is kept that long
    "COM_OBL_RC_ACT": 5,  # then the vehicle stops and holds, as ArduCopter's GUIDED does
    "MPC_LAND_SPEED": 0.6,  # LAND_SPEED 50 cm/s is below the core's floor; the nearest it takes
    "COM_RC_IN_MODE": 4,  # no stick input: ALT_HOLD and POSHOLD hold the position as they did before sticks
    # RC_CHANNELS_OVERRIDE (``rc.py``) flies on the core's sticks: ArduCopter's dead zones, not the core's; full
    # stick tilts ANGLE_MAX's default 30 deg; an override that times out (RC_OVERRIDE_TIME, set by the dialect)
    # leaves SITL's radio at low throttle: the vehicle lands (in GUIDED, AUTO and hold sticks do not count)
    "MPC_HOLD_DZ": 0.0,
    "MPC_MAN_TILT_MAX": 30.0,
    "COM_RC_LOSS_T": 3.0,
    "NAV_RCL_ACT": 3,
    "COM_RCL_EXCEPT": 7,
}
"""Core parameter defaults of an ArduCopter vehicle (ArduCopter's defaults in core units)."""

STREAM_GROUPS = ("RAW_SENS", "EXT_STAT", "RC_CHAN", "RAW_CTRL", "POSITION", "EXTRA1", "EXTRA2", "EXTRA3", "PARAMS")
"""The ``SRx_*`` stream-rate parameters (Hz), x = the link (0 SERIAL0 = TCP, 1 the API UDP port, 2 the GCS).
The server has one stream schedule for all links: a group goes out at the fastest rate of SR0..SR2, with
the defaults on SR0 (TCP) and 0 on the others: a request on TCP sets the rate, one on UDP can only raise it."""

STREAM_DEFAULT_HZ: dict[str, float] = {
    "RAW_SENS": 0.0,
    "EXT_STAT": 2.0,
    "RC_CHAN": 0.0,
    "RAW_CTRL": 0.0,
    "POSITION": 10.0,
    "EXTRA1": 10.0,
    "EXTRA2": 4.0,
    "EXTRA3": 2.0,
    "PARAMS": 0.0,
}
LINKS = 3

FENCE_ACTION_TO_CORE = {0: 1, 1: 3, 2: 5, 3: 3, 4: 2, 5: 3}
"""FENCE_ACTION (0 report, 1 RTL, 2 land, 3 SmartRTL, 4 brake, 5 SmartRTL or land) -> GF_ACTION."""


def _own(name: str, default: float, lo: float, hi: float, unit: str = "", desc: str = "") -> ParamDef:
    return ParamDef(name, ParamType.FLOAT, float(default), lo, hi, unit, desc)


def _own_i(name: str, default: int, lo: int, hi: int, desc: str = "") -> ParamDef:
    return ParamDef(name, ParamType.INT32, default, lo, hi, "", desc)


def own_defs(sysid: int) -> tuple[ParamDef, ...]:
    defs = [
        _own_i("SYSID_THISMAV", sysid, 1, 255, "MAVLink system id of this vehicle (read only here)"),
        _own_i("SYSID_MYGCS", 255, 1, 255),
        _own_i("FRAME_CLASS", 1, 0, 15, "1 = quad"),
        _own_i("FRAME_TYPE", 1, 0, 19, "1 = X"),
        _own_i("ARMING_CHECK", 1, 0, 0x7FFFFFFF, "0 skips the pre-arm checks"),
        _own_i("FENCE_ENABLE", 0, 0, 1),
        _own_i("FENCE_TYPE", 7, 0, 15, "bit 0 max altitude, bit 1 circle around home"),
        _own_i("FENCE_ACTION", 1, 0, 5),
        _own("FENCE_ALT_MAX", 100.0, 10.0, 1000.0, "m"),
        _own("FENCE_RADIUS", 150.0, 30.0, 10000.0, "m"),
        _own("CIRCLE_RADIUS", 1000.0, 0.0, 200000.0, "cm"),
        _own("CIRCLE_RATE", 20.0, -90.0, 90.0, "deg/s"),
        _own_i("BATT_MONITOR", 4, 0, 30),
        _own_i("GPS_TYPE", 1, 0, 26),
        _own_i("AHRS_EKF_TYPE", 3, 0, 11),
        _own_i("EK3_ENABLE", 1, 0, 1),
    ]
    for x in range(LINKS):  # defaults on SR0; a link's request raises its own SRx
        defs += [_own(f"SR{x}_{g}", STREAM_DEFAULT_HZ[g] if x == 0 else 0.0, 0.0, 50.0, "Hz") for g in STREAM_GROUPS]
    return tuple(defs)


_INT32 = (-2147483648.0, 2147483647.0)


def copter_table() -> ParamTable:
    """ArduCopter's parameter table (read once per process)."""
    return parse_param_table(copter_text(), "ArduCopter's parameter table (params_data/copter_params.tsv)")


def stored_value(ptype: ParamType, value: float) -> float:
    """The value ArduCopter keeps for a PARAM_SET of ``value`` (``AP_Param::set_float``): floats as given, integers
    truncated after adding 0.01 away from zero, within the type's limits (INT32 here: the table has no widths)."""
    v = float(value)
    if ptype != ParamType.INT32 or not math.isfinite(v):
        return v
    v += 0.01 if v >= 0 else -0.01
    return float(int(min(max(v, _INT32[0]), _INT32[1])))


class CopterParams(Params):
    """ArduCopter-named parameters, kept in step with the core registry ``core``."""

    def __init__(self, core: Params, sysid: int) -> None:
        self.core = core
        self._mapped = {m.name: m for m in MAPPED if m.core in core}
        self._by_core: dict[str, list[Mapped]] = {}
        for m in self._mapped.values():
            self._by_core.setdefault(m.core, []).append(m)
        table = copter_table()
        mapped_defs = []
        for m in self._mapped.values():
            d = core.definition(m.core)
            assert d is not None
            lo, hi = d.min * m.scale, d.max * m.scale  # every value the core can show, and ArduCopter's range
            ap_range = table.ranges.get(m.name, m.ap_range)  # the table's (ArduCopter 4.2) where it has one
            if ap_range is not None:
                lo, hi = min(lo, ap_range[0]), max(hi, ap_range[1])
            mapped_defs.append(ParamDef(m.name, m.type, round(d.default * m.scale, 6), lo, hi, m.unit))
        special = {d.name: d for d in (*mapped_defs, *own_defs(sysid))}
        self.special = frozenset(special)
        """Mapped and own parameters: flown or applied (the rest of the table is stored only)."""
        self.table = table
        super().__init__((*(special.pop(d.name, d) for d in table.defs), *special.values()))
        self._syncing = False
        for m in self._mapped.values():  # current core values (overrides included)
            super().set(m.name, self._from_core(m, core[m.core]))
        core.subscribe(self._core_changed)

    @staticmethod
    def _from_core(m: Mapped, value: float) -> float:
        v = value * m.scale
        return float(round(v)) if m.type == ParamType.INT32 else round(v, 6)

    def set(self, name: str, value: float) -> CommandResult:
        m = self._mapped.get(name)
        if m is not None and not self._syncing:
            return self._set_mapped(m, value)
        if name == "SYSID_THISMAV" and name in self and value != self[name]:
            return CommandResult.denied("SYSID_THISMAV is fixed by the run (the vehicle index + 1)")
        if name not in self.special and not self._syncing:
            if name in self.table.read_only:
                return CommandResult.denied(f"Param write denied ({name})")
            d = self.definition(name)
            if d is not None:
                value = stored_value(d.type, value)
        r = super().set(name, value)
        if r.ok and name.startswith("FENCE_"):
            self.apply_fence()
        return r

    def _set_mapped(self, m: Mapped, value: float) -> CommandResult:
        """Validate in ArduPilot's range, store as given, give the core the nearest value it takes."""
        old = self[m.name]
        r = super().set(m.name, value)
        if not r.ok:
            return r
        d = self.core.definition(m.core)
        assert d is not None
        core_value = min(max(float(value) / m.scale, d.min), d.max)
        if core_value != float(value) / m.scale:
            log.info("%s=%g: the core flies %s=%g (the nearest it takes)", m.name, value, m.core, core_value)
        self._syncing = True  # the core's change is not shown back: the value stays as the script set it
        try:
            rc = self.core.set(m.core, core_value)
            for other in self._by_core.get(m.core, ()) if rc.ok else ():  # THR_MID and MOT_THST_HOVER
                if other is not m:
                    super().set(other.name, self._from_core(other, core_value))
        finally:
            self._syncing = False
        if not rc.ok:
            super().set(m.name, old)
            return CommandResult.denied(f"{m.name}={value}: {rc.reason} (as {m.core})")
        return r

    def _core_changed(self, core_name: str, value: float) -> None:
        if self._syncing:
            return
        self._syncing = True
        try:
            for m in self._by_core.get(core_name, ()):
                super().set(m.name, self._from_core(m, value))
        finally:
            self._syncing = False

    def apply_fence(self) -> None:
        """FENCE_* to the core's GF_* limits (0 = off)."""
        enabled = int(self["FENCE_ENABLE"]) == 1
        kind = int(self["FENCE_TYPE"])
        alt = self["FENCE_ALT_MAX"] if enabled and kind & 1 else 0.0
        radius = self["FENCE_RADIUS"] if enabled and kind & 2 else 0.0
        for core_name, v in (
            ("GF_MAX_VER_DIST", alt),
            ("GF_MAX_HOR_DIST", radius),
            ("GF_ACTION", FENCE_ACTION_TO_CORE.get(int(self["FENCE_ACTION"]), 3)),
        ):
            if core_name in self.core:
                r = self.core.set(core_name, v)
                if not r.ok:
                    log.warning("fence parameter not applied: %s", r.reason)

    def stream_hz(self, group: str) -> float:
        """The fastest rate any link asks for this stream group."""
        return max(self[f"SR{x}_{group}"] for x in range(LINKS))
