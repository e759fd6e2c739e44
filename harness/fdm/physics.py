"""Physics of N quad-X vehicles in JSBSim, stepped in lockstep: the clock owner of a run.

``Physics.step(motors)`` applies one command per vehicle for one tick (``substep_hz / tick_hz`` JSBSim
steps) and returns every vehicle's sensor frame at the new tick. Commands are validated first: NaN,
infinite or out-of-range values are clamped (NaN to 0) and counted, never passed to JSBSim. A vehicle
that hits the ground faster than ``crash_speed_m_s`` is marked crashed (reported in its frame, motors
cut), never silently bounced.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import jsbsim
import numpy as np

from harness.core.errors import ScenarioError, SimulationError
from harness.core.geo import Vec3, quat_from_euler
from harness.fdm.config import PhysicsConfig, SensorConfig
from harness.fdm.environment import TURBULENCE_LEVELS, Turbulence, WindConfig, WorldChange, WorldOrigin
from harness.fdm.frame import MOTOR_COUNT, SensorFrame, Truth
from harness.fdm.params import FT_PER_M, G_M_S2, M_PER_FT, N_PER_LBF, models_root
from harness.fdm.sensors import SensorModel

__all__ = ["TURBULENCE_LEVELS", "Physics", "PhysicsConfig", "SensorConfig", "WindConfig", "WorldOrigin"]

_READ = (
    "position/lat-geod-deg",
    "position/long-gc-deg",
    "position/h-sl-ft",
    "velocities/v-north-fps",
    "velocities/v-east-fps",
    "velocities/v-down-fps",
    "attitude/phi-rad",
    "attitude/theta-rad",
    "attitude/psi-rad",
    "velocities/p-rad_sec",
    "velocities/q-rad_sec",
    "velocities/r-rad_sec",
    "forces/fbx-total-lbs",
    "forces/fby-total-lbs",
    "forces/fbz-total-lbs",
    "forces/fbz-gear-lbs",
)


@dataclass
class VehicleCounters:
    clamped_commands: int = 0
    nan_commands: int = 0


jsbsim.FGJSBBase().debug_lvl = 0  # no start-up banner on stdout (a mission's or the CLI's output)


class _Vehicle:
    def __init__(self, index: int, cfg: PhysicsConfig, rng: np.random.Generator) -> None:
        self.index = index
        self.cfg = cfg
        q = cfg.quad
        fdm = jsbsim.FGFDMExec(str(models_root()), None)
        fdm.set_debug_level(0)
        if not fdm.load_model("quadx"):
            raise SimulationError("JSBSim could not load the quadx model from the package data")
        n, e, d = cfg.spawn(index)
        lat, lon, _ = cfg.origin.ned_to_geodetic(n, e, 0.0)
        fdm["ic/terrain-elevation-ft"] = cfg.origin.alt_amsl_m * FT_PER_M
        fdm["ic/lat-geod-deg"] = lat
        fdm["ic/long-gc-deg"] = lon
        fdm["ic/h-agl-ft"] = (max(0.0, -d) + q.skid_below_cg_m) * FT_PER_M
        fdm["ic/psi-true-deg"] = cfg.heading_deg
        fdm.set_dt(1.0 / cfg.substep_hz)
        if not cfg.drag:
            fdm["aero/cda-ft2"] = 0.0
            fdm["aero/rotor-drag-lbf-per-fps"] = 0.0
        if not fdm.run_ic():
            raise SimulationError(f"JSBSim refused the initial conditions of vehicle {index}")
        pm = fdm.get_property_manager()
        self.fdm = fdm

        def node(name: str) -> jsbsim.FGPropertyNode:
            found = pm.get_node(name, False)
            if found is None:
                raise SimulationError(f"JSBSim model quadx has no property {name}")
            return found

        self.cmd_nodes = [node(f"fcs/motor-cmd[{i}]") for i in range(MOTOR_COUNT)]
        self.read_nodes = [node(name) for name in _READ]
        self.wind_nodes = [node(f"atmosphere/wind-{a}-fps") for a in ("north", "east", "down")]
        # per-step shortcuts: bound property accessors (the fastest read in jsbsim 1.3: ~0.12 µs a property,
        # against ~0.17 for fdm[name] and ~0.9 for get_property_value) and the world origin's constants
        self.cmd_setters = [n.set_double_value for n in self.cmd_nodes]
        self.wind_setters = [n.set_double_value for n in self.wind_nodes]
        self.reads = [n.get_double_value for n in self.read_nodes]
        o = cfg.origin
        self.lat0_deg, self.lon0_deg, self.alt0_m = o.lat_deg, o.lon_deg, o.alt_amsl_m
        self.r_meridian_m, self.r_normal_m = o.radii_m()
        self.cos_lat0 = math.cos(math.radians(o.lat_deg))
        self.mass_kg = q.mass_kg
        self.cos_tip_over = math.cos(math.radians(cfg.tip_over_deg))
        self.sensors = SensorModel(cfg.sensors, rng, round(1e9 / cfg.tick_hz), cfg.origin.magnetic_field_ned_gauss())
        self.turbulence = Turbulence(cfg.wind, rng)
        self.counters = VehicleCounters()
        self.crashed = False
        self.resting = d >= 0.0
        """Spawned standing on the ground: on the ground before the first step too (JSBSim computes the
        gear's force only when it steps, so the initial frame would otherwise read "not on the ground")."""
        self.airborne = False
        self.last_v_down = 0.0
        self.impact_speed_m_s = 0.0
        self.motors = (0.0, 0.0, 0.0, 0.0)


class Physics:
    """N vehicles in lockstep. Not thread-safe: one caller steps it.

    ``vehicles``: the indices (of ``cfg.n_vehicles``) this instance simulates, default all of them. Each
    vehicle is the same wherever it is simulated (its spawn point and its random stream, the ``i``-th child
    of the run's seed), so a run whose worker processes each step a share has the same ground truth as one
    process stepping all. ``step`` takes one command per simulated vehicle, in ``vehicles`` order; with no
    vehicles it only advances the clock.
    """

    def __init__(self, cfg: PhysicsConfig, vehicles: Sequence[int] | None = None) -> None:
        self.cfg = cfg
        self.substeps = round(cfg.substep_hz / cfg.tick_hz)
        self.tick_ns = round(1e9 / cfg.tick_hz)
        own = list(range(cfg.n_vehicles)) if vehicles is None else list(vehicles)
        bad = [i for i in own if not 0 <= i < cfg.n_vehicles]
        if bad or len(set(own)) != len(own):
            raise ScenarioError(f"physics: vehicles {own} are not distinct indices below {cfg.n_vehicles}")
        seeds = np.random.SeedSequence(cfg.seed).spawn(cfg.n_vehicles)
        self.vehicles = [_Vehicle(i, cfg, np.random.default_rng(seeds[i])) for i in own]
        self.owned: tuple[int, ...] = tuple(own)
        """The vehicles simulated here, in ``step`` order."""
        self._by_index = {v.index: v for v in self.vehicles}
        self._t_ns = 0
        self._tick = 0
        self._frames = [self._frame(v) for v in self.vehicles]

    @property
    def t_ns(self) -> int:
        return self._t_ns

    @property
    def tick(self) -> int:
        return self._tick

    def frames(self) -> list[SensorFrame]:
        return list(self._frames)

    def counters(self, vehicle: int) -> VehicleCounters:
        return self._by_index[vehicle].counters

    def crashed(self, vehicle: int) -> bool:
        return self._by_index[vehicle].crashed

    def set_wind(self, wind: WindConfig) -> None:
        """Change the wind of every vehicle (tests, scenario events)."""
        for v in self.vehicles:
            v.turbulence = Turbulence(wind, v.sensors.rng)

    def apply(self, vehicle: int, change: WorldChange) -> None:
        """A change of ``vehicle``'s world from its autopilot, before the next step (a vehicle simulated
        elsewhere is not this instance's business)."""
        v = self._by_index.get(vehicle)
        if v is None:
            return
        wind = change.wind(v.turbulence.cfg)
        if wind is not None:
            v.turbulence = Turbulence(wind, v.sensors.rng)

    def step(self, motors: Sequence[Sequence[float]]) -> list[SensorFrame]:
        if len(motors) != len(self.vehicles):
            raise SimulationError(
                f"physics: got motor commands for {len(motors)} vehicles, simulating {len(self.vehicles)}"
            )
        dt_tick = self.tick_ns * 1e-9
        substeps = range(self.substeps)
        for v, cmd in zip(self.vehicles, motors, strict=True):
            u = self._validate(v, cmd)
            v.motors = u
            s0, s1, s2, s3 = v.cmd_setters
            s0(u[0])
            s1(u[1])
            s2(u[2])
            s3(u[3])
            wn, we, wd = v.turbulence.step(dt_tick)
            w0, w1, w2 = v.wind_setters
            w0(wn * FT_PER_M)
            w1(we * FT_PER_M)
            w2(wd * FT_PER_M)
            run = v.fdm.run
            for _ in substeps:
                run()
            v.resting = False
        self._t_ns += self.tick_ns
        self._tick += 1
        self._frames = [self._frame(v) for v in self.vehicles]
        return list(self._frames)

    def _validate(self, v: _Vehicle, cmd: Sequence[float]) -> tuple[float, float, float, float]:
        if len(cmd) != MOTOR_COUNT:
            raise SimulationError(
                f"physics: vehicle {v.index} got {len(cmd)} motor commands, a quad-X needs {MOTOR_COUNT}"
            )
        if v.crashed:
            return (0.0, 0.0, 0.0, 0.0)
        c0, c1, c2, c3 = float(cmd[0]), float(cmd[1]), float(cmd[2]), float(cmd[3])
        if 0.0 <= c0 <= 1.0 and 0.0 <= c1 <= 1.0 and 0.0 <= c2 <= 1.0 and 0.0 <= c3 <= 1.0:
            return (c0, c1, c2, c3)  # the usual case (NaN fails every comparison)
        out = []
        for x in (c0, c1, c2, c3):
            if x != x:  # NaN
                v.counters.nan_commands += 1
                v.counters.clamped_commands += 1
                x = 0.0
            elif x < 0.0 or x > 1.0:  # also catches ±inf
                v.counters.clamped_commands += 1
                x = 0.0 if x < 0.0 else 1.0
            out.append(x)
        return (out[0], out[1], out[2], out[3])

    def _frame(self, v: _Vehicle) -> SensorFrame:
        (lat, lon, h_ft, vn, ve, vd, phi, theta, psi, p, q, r, fx, fy, fz, fgear) = [read() for read in v.reads]
        alt = h_ft * M_PER_FT
        # the world origin's geodetic_to_ned, with its constants taken once
        pos = (
            math.radians(lat - v.lat0_deg) * v.r_meridian_m,
            math.radians(lon - v.lon0_deg) * v.r_normal_m * v.cos_lat0,
            v.alt0_m - alt,
        )
        vel = (vn * M_PER_FT, ve * M_PER_FT, vd * M_PER_FT)
        quat = quat_from_euler(phi, theta, psi)
        m = v.mass_kg
        sf = (fx * N_PER_LBF / m, fy * N_PER_LBF / m, fz * N_PER_LBF / m)
        on_ground = abs(fgear) > 1e-3 or v.resting
        if on_ground:
            if v.airborne and not v.crashed:
                v.impact_speed_m_s = v.last_v_down
                if v.last_v_down > self.cfg.crash_speed_m_s:
                    v.crashed = True
            upright = 1.0 - 2.0 * (quat[1] ** 2 + quat[2] ** 2)  # cosine of the tilt
            if upright < v.cos_tip_over:
                v.crashed = True  # lying on its side or back
            v.airborne = False
        elif pos[2] < -(0.05):
            v.airborne = True
        v.last_v_down = vel[2]
        acc = _accel_ned(quat, sf)
        rates = (p, q, r)
        t_ns = self._t_ns
        truth = Truth(pos, vel, quat, rates, acc, lat, lon, alt, on_ground, v.crashed)
        imu, mag, baro, gps = v.sensors.sample(t_ns, quat, sf, rates, lat, lon, alt, vel)
        return SensorFrame(t_ns, v.index, imu, truth, mag, baro, gps)


def _accel_ned(q: tuple[float, float, float, float], sf: Vec3) -> Vec3:
    w, x, y, z = q
    ax, ay, az = sf
    return (
        (1 - 2 * (y * y + z * z)) * ax + 2 * (x * y - w * z) * ay + 2 * (x * z + w * y) * az,
        2 * (x * y + w * z) * ax + (1 - 2 * (x * x + z * z)) * ay + 2 * (y * z - w * x) * az,
        2 * (x * z - w * y) * ax + 2 * (y * z + w * x) * ay + (1 - 2 * (x * x + y * y)) * az + G_M_S2,
    )
