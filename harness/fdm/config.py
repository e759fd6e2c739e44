"""The sensor and physics configurations: plain frozen dataclasses that scenarios build and that a run sends to
its worker processes as JSON (``PhysicsConfig.to_json``).

They live apart from the models that use them (``harness.fdm.sensors``, ``harness.fdm.physics``, which re-export
them) because those modules are compiled by mypyc (``harness.core.native``), and a compiled dataclass does not
keep its field types in ``__annotations__`` (a tuple field shows as ``type``): msgspec, which decodes these
configurations, needs them.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Any

import msgspec

from harness.core.errors import ScenarioError
from harness.core.geo import Vec3
from harness.fdm.environment import WindConfig, WorldOrigin
from harness.fdm.params import DEFAULT_QUAD, QuadParams


def gps_profile_names() -> list[str]:
    return sorted(p.value for p in GpsProfile)


class GpsProfile(enum.StrEnum):
    """A GPS error model (its value is the scenario file's ``sensors.gps``)."""

    PX4_SITL = "px4-sitl"
    STANDALONE = "standalone"


GPS_PROFILES: dict[GpsProfile, dict[str, float]] = {
    GpsProfile.PX4_SITL: {"gps_noise_m": 0.026, "gps_alt_noise_m": 0.038, "gps_error_tau_s": 2.4},
    GpsProfile.STANDALONE: {"gps_noise_m": 0.3, "gps_alt_noise_m": 0.5, "gps_error_tau_s": 20.0},
}
"""GPS position error models (per-axis σ and correlation time of a Gauss-Markov error).

- ``px4-sitl`` (default): what PX4's own SITL adds in Gazebo (``SensorGpsSim``, "based on u-blox F9P"):
  centimetre level, decorrelating in about 2 s. Flights compare with PX4 SITL; a hover holds ±0.2 m.
- ``standalone``: a single receiver without corrections, 0.3 m horizontal / 0.5 m vertical, wandering over
  tens of seconds. Every GPS-based position hold (PX4's too) follows this error: a hover wanders about
  ±0.4 m. Use it to test a mission's tolerance of real GPS.

(PX4's older Gazebo-classic plugin adds about 3 mm; real standalone receivers are often worse than
``standalone``, up to metres.)
"""


@dataclass(frozen=True)
class SensorConfig:
    noise: bool = True
    """Master switch: False gives ideal sensors (no noise, bias, drift; latency and rates stay)."""
    accel_noise_m_s2: float = 0.05
    """White noise, standard deviation per sample."""
    accel_bias_m_s2: Vec3 = (0.03, -0.02, 0.04)
    """Turn-on bias (what a calibration would leave)."""
    accel_bias_walk_m_s2_sqrt_s: float = 0.0005
    gyro_noise_rad_s: float = 0.004
    gyro_bias_rad_s: Vec3 = (0.002, -0.0015, 0.001)
    gyro_bias_walk_rad_s_sqrt_s: float = 0.00005
    mag_rate_hz: float = 50.0
    mag_noise_gauss: float = 0.003
    mag_bias_gauss: Vec3 = (0.002, -0.001, 0.0015)
    baro_rate_hz: float = 50.0
    baro_noise_m: float = 0.1
    """Pressure noise, expressed as the altitude it amounts to."""
    baro_bias_m: float = 0.3
    baro_drift_m_sqrt_s: float = 0.005
    gps_rate_hz: float = 10.0
    gps_latency_s: float = 0.1
    gps_noise_m: float = 0.026
    """Horizontal position error per axis: standard deviation of a first-order Gauss-Markov error with
    correlation time ``gps_error_tau_s``. The defaults are the ``px4-sitl`` profile (:data:`GPS_PROFILES`)."""
    gps_alt_noise_m: float = 0.038
    gps_error_tau_s: float = 2.4
    gps_vel_noise_m_s: float = 0.05
    gps_fix_type: int = 3
    gps_satellites: int = 12

    @classmethod
    def for_gps(cls, profile: GpsProfile | str, **overrides: Any) -> SensorConfig:
        """The sensors with the GPS error of ``profile`` (a :class:`GpsProfile` or its value)."""
        if profile not in GPS_PROFILES:
            raise ScenarioError(f"sensors: unknown GPS profile {profile!r}; choose one of {gps_profile_names()}")
        return cls(**(GPS_PROFILES[GpsProfile(profile)] | overrides))

    def __post_init__(self) -> None:
        for name in ("mag_rate_hz", "baro_rate_hz", "gps_rate_hz", "gps_error_tau_s"):
            if not getattr(self, name) > 0:
                raise ScenarioError(f"sensors: {name} must be > 0, got {getattr(self, name)}")
        if self.gps_latency_s < 0:
            raise ScenarioError(f"sensors: gps_latency_s must be >= 0, got {self.gps_latency_s}")


@dataclass(frozen=True)
class PhysicsConfig:
    n_vehicles: int = 1
    seed: int = 0
    substep_hz: float = 1000.0
    tick_hz: float = 250.0
    origin: WorldOrigin = field(default_factory=WorldOrigin)
    wind: WindConfig = field(default_factory=WindConfig)
    spawn_ned_m: tuple[Vec3, ...] | None = None
    """Where each vehicle starts (on the ground when d = 0); default: a grid 5 m apart."""
    spawn_spacing_m: float = 5.0
    heading_deg: float = 0.0
    """Every vehicle's heading at the start (true, degrees)."""
    sensors: SensorConfig = field(default_factory=SensorConfig)
    drag: bool = True
    crash_speed_m_s: float = 3.0
    tip_over_deg: float = 60.0
    """Tilt at which a vehicle touching the ground has tipped over (crashed)."""
    quad: QuadParams = DEFAULT_QUAD

    def __post_init__(self) -> None:
        if self.n_vehicles < 1:
            raise ScenarioError(f"physics: n_vehicles must be >= 1, got {self.n_vehicles}")
        if not self.tick_hz > 0 or not self.substep_hz > 0:
            raise ScenarioError(f"physics: rates must be > 0 (substep_hz={self.substep_hz}, tick_hz={self.tick_hz})")
        ratio = self.substep_hz / self.tick_hz
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ScenarioError(
                f"physics: substep_hz ({self.substep_hz}) must be a whole multiple of tick_hz ({self.tick_hz})"
            )
        if self.spawn_ned_m is not None and len(self.spawn_ned_m) != self.n_vehicles:
            raise ScenarioError(
                f"physics: {len(self.spawn_ned_m)} spawn positions given for {self.n_vehicles} vehicles"
            )

    def spawn(self, i: int) -> Vec3:
        if self.spawn_ned_m is not None:
            return self.spawn_ned_m[i]
        cols = max(1, math.ceil(math.sqrt(self.n_vehicles)))
        return (-(i // cols) * self.spawn_spacing_m, (i % cols) * self.spawn_spacing_m, 0.0)

    def to_json(self) -> bytes:
        """This configuration as JSON (every float exact): what a worker process builds its share from."""
        return msgspec.json.encode(self)

    @classmethod
    def from_json(cls, data: bytes | str) -> PhysicsConfig:
        """The configuration :meth:`to_json` wrote; :class:`ScenarioError` if ``data`` is not one."""
        try:
            return msgspec.json.decode(data, type=cls)
        except (msgspec.DecodeError, msgspec.ValidationError) as exc:
            raise ScenarioError(f"physics: not a physics configuration: {exc}") from None
