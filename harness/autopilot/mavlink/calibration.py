"""Sensor calibration as PX4's commander runs it (MAV_CMD_PREFLIGHT_CALIBRATION, 241), against the
simulated sensors, reporting progress in the ``[cal]`` STATUSTEXTs QGroundControl and MAVSDK parse
(MAVSDK ``calibration_statustext_parser.cpp``, PX4 ``calibration_messages.h``):

    [cal] calibration started: 2 <gyro|accel|mag|level>
    [cal] progress <N>                                   gyro, level, accel (17 per side)
    [cal] pending: back front left right up down         accel, mag
    [cal] <side> orientation detected
    [cal] <side> side calibration: progress <N>          mag
    [cal] <side> side done, rotate to a different side   accel, mag
    [cal] calibration done: <kind>
    [cal] calibration failed: <reason>                   armed, or sensor data missing
    [cal] calibration cancelled                          all parameters 0

Command parameters (MAVSDK sends these): param1 = 1 gyro, param2 = 1 magnetometer, param5 = 1
accelerometer, param5 = 2 level horizon; all zero cancels. Refused when armed (DENIED) or while another
calibration runs (TEMPORARILY_REJECTED); other kinds (baro, RC, airspeed, temperature) are UNSUPPORTED.

What is measured (sim time, from the autopilot's state each tick; the vehicle must stay on the ground):
gyro offsets = the mean gyro reading over 2 s; the level horizon = the roll and pitch of the mean specific
force over 2 s (``SENS_BOARD_X_OFF`` / ``_Y_OFF``, degrees); accelerometer = the mean specific force on the
side it rests on, 1 s. The simulated vehicle cannot be turned over: the other five sides (accelerometer) and
all six (magnetometer) are taken from that reading rotated to each side — a virtual turntable — so the
accelerometer's offsets come from the resting side and its scales stay 1, and the magnetometer's offsets are 0
(a sphere centred on zero; the simulated magnetometer has no hard iron). Results go to PX4's per-instance
parameters (``CAL_GYRO0_*``, ``CAL_ACC0_*``, ``CAL_MAG0_*`` with SITL's device ids), which the flight core
does not read: calibration changes nothing in how the vehicle flies.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from harness.autopilot.api import CommandResult, Severity, VehicleState
from harness.autopilot.mavlink.commands import CommandIn, CommandOutcome
from harness.autopilot.mavlink.messages import Out
from harness.autopilot.mavlink.service import CommandHandler, Service, outcome
from harness.autopilot.params import SITL_ACCEL_ID, SITL_GYRO_ID, SITL_MAG_ID
from harness.autopilot.services import System

CMD_PREFLIGHT_CALIBRATION = 241
G = 9.80665
SIDES = ("down", "up", "left", "right", "front", "back")
"""Order the virtual turntable presents the sides in (PX4 takes them in whatever order they come)."""
PENDING_ORDER = ("back", "front", "left", "right", "up", "down")
"""The order of PX4's "[cal] pending: ..." list."""
GYRO_NS = 2_000_000_000
LEVEL_NS = 2_000_000_000
SIDE_NS = 1_000_000_000


class Kind(enum.Enum):
    GYRO = "gyro"
    ACCEL = "accel"
    MAG = "mag"
    LEVEL = "level"


def kind_of(c: CommandIn) -> Kind | str | None:
    """The calibration a command asks for; None to cancel; a str for an unsupported request."""
    p = [0.0 if math.isnan(v) else v for v in c.params]  # MAVSDK sends NaN for what it leaves unset
    if any(math.isinf(v) for v in p):
        return "calibration: parameters must be finite"
    if all(v == 0 for v in p):
        return None
    if p[0] == 1:
        return Kind.GYRO
    if p[1] == 1:
        return Kind.MAG
    if p[4] == 1:
        return Kind.ACCEL
    if p[4] == 2:
        return Kind.LEVEL
    return "only gyro, accelerometer, magnetometer and level calibration are simulated"


@dataclass(slots=True)
class _Run:
    kind: Kind
    start_ns: int | None = None
    """Sim time of the first tick after the command."""
    samples: list[tuple[float, float, float]] = field(default_factory=list)
    last_t_ns: int = -1
    reported: int = 0
    """Progress steps already reported (tenths, or sides done)."""
    side_started: bool = False


def _mean(samples: list[tuple[float, float, float]]) -> tuple[float, float, float]:
    n = len(samples)
    return (sum(s[0] for s in samples) / n, sum(s[1] for s in samples) / n, sum(s[2] for s in samples) / n)


class CalibrationService(Service):
    def __init__(self, api: System) -> None:
        super().__init__()
        self.api = api
        self._run: _Run | None = None
        self._queued: list[tuple[Severity, str]] = []

    @property
    def running(self) -> Kind | None:
        return self._run.kind if self._run is not None else None

    def commands(self) -> Mapping[int, CommandHandler]:
        return {CMD_PREFLIGHT_CALIBRATION: self._command}

    def _command(self, c: CommandIn) -> CommandOutcome:
        kind = kind_of(c)
        if kind is None:
            if self._run is not None:
                self._run = None
                self._queued.append((Severity.INFO, "[cal] calibration cancelled"))
            return outcome(CommandResult.accepted())
        if isinstance(kind, str):
            bad = kind.endswith("finite")
            return outcome(CommandResult.denied(kind) if bad else CommandResult.unsupported(kind))
        if self.api.telemetry.state().armed:
            return outcome(CommandResult.denied("[cal] calibration denied: system armed"))
        if self._run is not None:
            return outcome(CommandResult.rejected("[cal] calibration denied: already running"))
        self._run = _Run(kind)
        self._queued.append((Severity.INFO, f"[cal] calibration started: 2 {kind.value}"))
        if kind in (Kind.ACCEL, Kind.MAG):
            self._queued.append((Severity.INFO, "[cal] pending: " + " ".join(PENDING_ORDER)))
            self._queued.append((Severity.INFO, "[cal] hold vehicle still on a pending side"))
        return outcome(CommandResult.accepted())

    # ------------------------------------------------------------------ sim time
    def tick(self, state: VehicleState, now: int) -> list[Out]:
        run = self._run
        if run is not None:
            self._advance(run, state)
        queued, self._queued = self._queued, []
        return [self.text(sev, text) for sev, text in queued]

    def _say(self, text: str, severity: Severity = Severity.INFO) -> None:
        self._queued.append((severity, text))

    def _fail(self, reason: str) -> None:
        self._say(f"[cal] calibration failed: {reason}", Severity.CRITICAL)
        self._run = None

    def _advance(self, run: _Run, state: VehicleState) -> None:
        if state.armed or state.in_air:
            self._fail("vehicle armed or in air")
            return
        if state.t_ns <= run.last_t_ns:
            return  # no new sample since the last tick (the wall clock serviced the server)
        run.last_t_ns = state.t_ns
        if run.start_ns is None:
            run.start_ns = state.t_ns
            return
        elapsed = state.t_ns - run.start_ns
        if run.kind is Kind.GYRO:
            run.samples.append(state.rates_body_rad_s)
            if self._progress(run, elapsed, GYRO_NS):
                x, y, z = _mean(run.samples)
                self._store("GYRO", SITL_GYRO_ID, (x, y, z), None)
                self._done(run)
        elif run.kind is Kind.LEVEL:
            run.samples.append(state.accel_body_m_s2)
            if self._progress(run, elapsed, LEVEL_NS):
                ax, ay, az = _mean(run.samples)
                roll = math.degrees(math.atan2(-ay, -az))
                pitch = math.degrees(math.atan2(ax, math.hypot(ay, az)))
                self.api.params.set("SENS_BOARD_X_OFF", round(roll, 4))
                self.api.params.set("SENS_BOARD_Y_OFF", round(pitch, 4))
                self._done(run)
        else:
            self._sides(run, state, elapsed)

    def _progress(self, run: _Run, elapsed: int, total: int) -> bool:
        """Report every 10 % of ``total``; True when it is over."""
        tenths = min(10, elapsed * 10 // total)
        while run.reported < tenths:
            run.reported += 1
            self._say(f"[cal] progress <{run.reported * 10}>")
        return elapsed >= total

    def _sides(self, run: _Run, state: VehicleState, elapsed: int) -> None:
        side_index = min(len(SIDES) - 1, elapsed // SIDE_NS)
        if run.kind is Kind.ACCEL and side_index == 0:
            run.samples.append(state.accel_body_m_s2)
        elif run.kind is Kind.MAG and side_index == 0 and state.mag_body_gauss is not None:
            run.samples.append(state.mag_body_gauss)
        while run.reported <= side_index:
            side = SIDES[run.reported]
            if not run.side_started:
                run.side_started = True
                self._say(f"[cal] {side} orientation detected")
                if run.kind is Kind.MAG:
                    for pct in (25, 50, 75, 100):
                        self._say(f"[cal] {side} side calibration: progress <{pct}>")
            if run.reported == side_index and elapsed < (side_index + 1) * SIDE_NS:
                return  # this side is still being held
            run.reported += 1
            run.side_started = False
            if run.kind is Kind.ACCEL:
                self._say(f"[cal] progress <{min(100, 17 * run.reported)}>")
            left = [s for s in PENDING_ORDER if s in SIDES[run.reported :]]
            self._say(f"[cal] {side} side done, rotate to a different side")
            if left:
                self._say("[cal] pending: " + " ".join(left))
        if run.reported < len(SIDES):
            return
        if not run.samples:
            self._fail("reading sensor")
            return
        if run.kind is Kind.ACCEL:
            ax, ay, az = _mean(run.samples)
            self._store("ACC", SITL_ACCEL_ID, (ax, ay, az + G), (1.0, 1.0, 1.0))
        else:
            self._store("MAG", SITL_MAG_ID, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
        self._done(run)

    def _store(
        self, sensor: str, device_id: int, offsets: tuple[float, float, float], scales: tuple[float, ...] | None
    ) -> None:
        api = self.api
        for axis, off in zip("XYZ", offsets, strict=True):
            api.params.set(f"CAL_{sensor}0_{axis}OFF", round(off, 6))
        if scales is not None:
            for axis, sc in zip("XYZ", scales, strict=True):
                api.params.set(f"CAL_{sensor}0_{axis}SCALE", sc)
        api.params.set(f"CAL_{sensor}0_ID", device_id)
        api.params.set(f"CAL_{sensor}0_PRIO", 50)

    def _done(self, run: _Run) -> None:
        self._say(f"[cal] calibration done: {run.kind.value}")
        self._run = None
