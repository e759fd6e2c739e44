"""A closed-loop rig: one autopilot flying one vehicle of a plant (the real FDM, or the small test quad).

Measurements come from the frames' ground truth; the autopilot itself only reads sensors.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

import numpy as np

from harness.autopilot.api import FlightMode
from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.core.clock import ManualClock
from harness.core.geo import GeoRef
from harness.fdm.frame import SensorFrame
from tests.autopilot.quadsim import QuadSim


class Plant(Protocol):
    def frames(self) -> list[SensorFrame]: ...
    def step(self, motors: list[tuple[float, ...]]) -> list[SensorFrame]: ...


class QuadPlant:
    def __init__(self, seed: int = 0) -> None:
        self.sim = QuadSim(np.random.default_rng(seed))

    def frames(self) -> list[SensorFrame]:
        return [self.sim.frame()]

    def step(self, motors: list[tuple[float, ...]]) -> list[SensorFrame]:
        return [self.sim.step(motors[0])]


class FlightRig:
    def __init__(self, plant: Plant, **params: float) -> None:
        self.plant = plant
        self.clock = ManualClock()
        self.ap = Autopilot(AutopilotConfig(params=params), wall_clock=self.clock)
        self.frame = plant.frames()[0]
        self.log: list[tuple[float, tuple[float, float, float], tuple[float, float, float]]] = []
        """(t_s, true position NED, true velocity NED) at every tick."""
        self.on_tick: Callable[[], object] | None = None
        self.run(2.0)
        t = self.frame.truth
        self.origin = GeoRef(t.lat_deg, t.lon_deg, t.alt_amsl_m)
        self.start = t.pos_ned_m

    @property
    def pos(self) -> tuple[float, float, float]:
        """True position relative to where the vehicle stood at the start."""
        p, s = self.frame.truth.pos_ned_m, self.start
        return (p[0] - s[0], p[1] - s[1], p[2] - s[2])

    @property
    def vel(self) -> tuple[float, float, float]:
        return self.frame.truth.vel_ned_m_s

    def run(self, seconds: float) -> None:
        f = self.frame
        end = f.t_ns + round(seconds * 1e9)
        while f.t_ns < end:
            self.clock.advance_to(max(f.t_ns, self.clock.now_ns()))
            if self.on_tick is not None:
                self.on_tick()
            motors = self.ap.step(f)
            f = self.plant.step([motors])[0]
            self.log.append((f.t_ns * 1e-9, f.truth.pos_ned_m, f.truth.vel_ned_m_s))
        self.frame = f

    def run_until(self, cond: Callable[[], bool], limit_s: float, step_s: float = 0.1) -> float:
        t = 0.0
        while t < limit_s:
            if cond():
                return t
            self.run(step_s)
            t += step_s
        raise AssertionError(f"condition not met within {limit_s} s: {self.ap.telemetry.state()}")

    def up(self, alt_m: float) -> None:
        assert self.ap.action.arm().ok, self.ap.telemetry.arming_check()
        assert self.ap.action.takeoff(alt_m).ok
        self.run_until(lambda: self.ap.telemetry.state().mode == FlightMode.HOLD, 30.0)

    def geo(self, n: float, e: float) -> tuple[int, int]:
        """Lat/lon (1e7 ints) of a point n, e metres from the start position."""
        lat, lon, _ = self.origin.to_geo(n, e, 0.0)
        return round(lat * 1e7), round(lon * 1e7)


def cross_track_m(p: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
    dx, dy = b[0] - a[0], b[1] - a[1]
    return abs(dx * (p[1] - a[1]) - dy * (p[0] - a[0])) / math.hypot(dx, dy)
