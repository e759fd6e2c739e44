"""The simulated world as ArduPilot SITL users change it: the ``SIM_*`` parameters, acting.

The parameters live in the vehicle's registry (``params.py``, ArduPilot's names and units; an ArduCopter vehicle
shows them under the same names, a scenario sets them in ``params``). A change acts where the real SITL's does:

- on the **sensors**, before the estimator sees them (as :mod:`harness.autopilot.failures` does for PX4's
  failure injection): ``SIM_GPS_DISABLE`` (no GPS samples), ``SIM_GPS_GLITCH_X/Y/Z`` (the fix shifted by
  degrees of latitude / longitude and metres), ``SIM_BARO_DISABLE``, ``SIM_BARO_GLITCH`` (metres),
  ``SIM_MAG1_FAIL``;
- on the **motors**, after the mixer, so the FDM flies on what is left: ``SIM_ENGINE_FAIL`` (a mask, bit 0 =
  motor 1) and ``SIM_ENGINE_MUL`` (their thrust command multiplied);
- on the **battery**: ``SIM_BATT_VOLTAGE`` sets the state of charge whose resting voltage it is (clipped to full);
- on the **physics** (another process, perhaps): ``SIM_WIND_SPD`` / ``SIM_WIND_DIR`` (where it comes from) /
  ``SIM_WIND_DIR_Z`` / ``SIM_WIND_TURB``, and the run's pace ``SIM_SPEEDUP``. These go out as one
  :class:`~harness.fdm.environment.WorldChange` on the END-TICK-AC of the tick after the change, and whoever
  steps the vehicle's physics applies it before the next physics step (a tick boundary, the same in every
  placement) and the run records it (``world.mcap`` ``/events``, kind ``sim``).

Nothing here runs per tick while every knob is at its default (``active`` is False).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable

import msgspec

from harness.autopilot.battery import Battery
from harness.autopilot.params import Params
from harness.fdm.environment import WorldChange
from harness.fdm.frame import SensorFrame

WIND = ("SIM_WIND_SPD", "SIM_WIND_DIR", "SIM_WIND_DIR_Z", "SIM_WIND_TURB")
SENSORS = (
    "SIM_GPS_DISABLE",
    "SIM_GPS_GLITCH_X",
    "SIM_GPS_GLITCH_Y",
    "SIM_GPS_GLITCH_Z",
    "SIM_BARO_DISABLE",
    "SIM_BARO_GLITCH",
    "SIM_MAG1_FAIL",
)
MOTORS = ("SIM_ENGINE_FAIL", "SIM_ENGINE_MUL")
NAMES = frozenset((*WIND, *SENSORS, *MOTORS, "SIM_BATT_VOLTAGE", "SIM_SPEEDUP"))
"""Every SIM_* parameter that acts (the rest of ArduPilot's are listed in docs/ardupilot.md as not modelled)."""

_PA_PER_M = 12.0
"""Pressure change per metre near the ground (ρ g with ρ ≈ 1.22 kg/m³): a baro glitch of h m lowers the
pressure by this much per metre."""


def wind_ned(speed_m_s: float, from_deg: float, dir_z_deg: float) -> tuple[float, float, float]:
    """The air's velocity (where it moves to, NED) for a wind of ``speed_m_s`` coming from ``from_deg`` (true),
    tilted ``dir_z_deg`` upwards (90: a pure updraft)."""
    d, z = math.radians(from_deg), math.radians(dir_z_deg)
    h = speed_m_s * math.cos(z)
    return (-h * math.cos(d), -h * math.sin(d), -speed_m_s * math.sin(z))


class SimWorld:
    """One vehicle's ``SIM_*`` knobs (the autopilot's ``world``). Parameter changes arrive on any thread; the
    stepping thread reads immutable snapshots."""

    def __init__(self, params: Params, battery: Callable[[], Battery]) -> None:
        self.params = params
        self._battery = battery
        self._lock = threading.Lock()
        self.active = False
        """True when a sensor or motor knob is away from its default (``Autopilot.step`` asks this only)."""
        self._sensor_knobs: tuple[float, ...] = ()
        self._motor_gain: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
        self._change: WorldChange | None = None
        self._pending_env = False
        self._pending_speed = False
        self.pending = False
        """True when ``take_change`` has something (the tick asks this only)."""
        self._update(set(NAMES), initial=True)
        params.subscribe(self._changed)

    # ------------------------------------------------------------------ parameter changes (any thread)
    def _changed(self, name: str, _value: float) -> None:
        if name in NAMES:
            self._update({name})

    def _update(self, names: set[str], initial: bool = False) -> None:
        p = self.params
        with self._lock:
            if names & set(SENSORS):
                knobs = tuple(p[n] for n in SENSORS)
                self._sensor_knobs = knobs if any(knobs) else ()
            if names & set(MOTORS):
                mask, mul = int(p["SIM_ENGINE_FAIL"]), p["SIM_ENGINE_MUL"]
                g = tuple(mul if mask >> i & 1 else 1.0 for i in range(4))
                self._motor_gain = (g[0], g[1], g[2], g[3])
            if names & set(WIND):
                self._pending_env = not (initial and p["SIM_WIND_SPD"] == 0 and p["SIM_WIND_TURB"] == 0)
            if "SIM_SPEEDUP" in names and not initial:
                self._pending_speed = True
            if "SIM_BATT_VOLTAGE" in names and not (initial and p["SIM_BATT_VOLTAGE"] >= self._full_v()):
                self._set_charge(p["SIM_BATT_VOLTAGE"])
            self.active = bool(self._sensor_knobs) or self._motor_gain != (1.0, 1.0, 1.0, 1.0)
            self.pending = self._pending_env or self._pending_speed

    def _full_v(self) -> float:
        p = self.params
        return p["BAT_N_CELLS"] * p["BAT_V_CHARGED"]

    def _set_charge(self, volts: float) -> None:
        """The charge whose resting voltage is ``volts`` (the inverse of ``Battery.open_circuit_v``)."""
        p = self.params
        bat = self._battery()
        cells, full, empty = p["BAT_N_CELLS"], p["BAT_V_CHARGED"], p["BAT_V_EMPTY"]
        frac = (min(volts, self._full_v()) / cells - empty) / (full - empty)
        soc = max(0.0, frac) ** (1 / 0.7)
        bat.consumed_mah = (1.0 - soc) * p["BAT_CAPACITY"]

    # ------------------------------------------------------------------ the tick (stepping thread)
    def take_change(self, t_ns: int) -> WorldChange | None:
        """What changed for the physics or the pace since the last call, to apply before the next physics step."""
        if not self.pending:
            return None
        p = self.params
        with self._lock:
            wind = turb = speed = None
            if self._pending_env:
                wind = wind_ned(p["SIM_WIND_SPD"], p["SIM_WIND_DIR"], p["SIM_WIND_DIR_Z"])
                turb = p["SIM_WIND_TURB"]
            if self._pending_speed:
                speed = p["SIM_SPEEDUP"]
            self._pending_env = self._pending_speed = self.pending = False
        return WorldChange(t_ns, wind, turb, speed)

    def sensors(self, frame: SensorFrame) -> SensorFrame:
        knobs = self._sensor_knobs
        if not knobs:
            return frame
        gps_off, glat, glon, galt, baro_off, baro_glitch, mag_off = knobs
        fields: dict[str, object] = {}
        gps = frame.gps
        if gps_off:
            fields["gps"] = None
        elif gps is not None and (glat or glon or galt):
            fields["gps"] = msgspec.structs.replace(
                gps, lat_deg=gps.lat_deg + glat, lon_deg=gps.lon_deg + glon, alt_amsl_m=gps.alt_amsl_m + galt
            )
        baro = frame.baro
        if baro_off:
            fields["baro"] = None
        elif baro is not None and baro_glitch:
            fields["baro"] = msgspec.structs.replace(
                baro, pressure_pa=baro.pressure_pa - _PA_PER_M * baro_glitch, alt_amsl_m=baro.alt_amsl_m + baro_glitch
            )
        if mag_off:
            fields["mag"] = None
        return msgspec.structs.replace(frame, **fields) if fields else frame

    def motors(self, motors: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        g = self._motor_gain
        return (motors[0] * g[0], motors[1] * g[1], motors[2] * g[2], motors[3] * g[3])
