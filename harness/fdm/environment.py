"""The world: origin, geodesy of the local NED frame, steady wind and seeded turbulence.

JSBSim's wind reaches a model only through its aerodynamic terms; the quad's drag is defined on the
airspeed (``aerodynamics`` in quadx.xml: body drag on dynamic pressure, rotor drag on true airspeed), so
the wind set here pushes the vehicle as a real wind would.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import msgspec
import numpy as np

from harness.core.errors import ScenarioError
from harness.core.geo import WGS84_A_M, WGS84_E2


@dataclass(frozen=True)
class WorldOrigin:
    lat_deg: float = 47.397742
    lon_deg: float = 8.545594
    alt_amsl_m: float = 488.0
    """Ground level at the origin (also the terrain elevation everywhere)."""

    def __post_init__(self) -> None:
        if not -90.0 < self.lat_deg < 90.0 or not -180.0 <= self.lon_deg <= 180.0:
            raise ScenarioError(f"world origin ({self.lat_deg}, {self.lon_deg}) is not a valid latitude/longitude")

    def radii_m(self) -> tuple[float, float]:
        """(meridian, prime-vertical) radii of curvature at the origin."""
        s = math.sin(math.radians(self.lat_deg))
        d = 1.0 - WGS84_E2 * s * s
        return WGS84_A_M * (1.0 - WGS84_E2) / d**1.5, WGS84_A_M / math.sqrt(d)

    def ned_to_geodetic(self, n_m: float, e_m: float, d_m: float) -> tuple[float, float, float]:
        rm, rn = self.radii_m()
        lat = self.lat_deg + math.degrees(n_m / rm)
        lon = self.lon_deg + math.degrees(e_m / (rn * math.cos(math.radians(self.lat_deg))))
        return lat, lon, self.alt_amsl_m - d_m

    def geodetic_to_ned(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> tuple[float, float, float]:
        rm, rn = self.radii_m()
        n = math.radians(lat_deg - self.lat_deg) * rm
        e = math.radians(lon_deg - self.lon_deg) * rn * math.cos(math.radians(self.lat_deg))
        return n, e, self.alt_amsl_m - alt_amsl_m

    def magnetic_field_ned_gauss(self) -> tuple[float, float, float]:
        """Earth's field at the origin from a tilted-dipole approximation (≈ ±10 % of WMM at mid
        latitudes): horizontal component north, vertical down in the northern hemisphere."""
        lat = math.radians(self.lat_deg)
        b0 = 0.31  # equatorial field strength of the dipole [gauss]
        h = b0 * math.cos(lat)
        z = 2.0 * b0 * math.sin(lat)
        decl = math.radians(3.0 if self.lon_deg > -30 else -10.0)
        return h * math.cos(decl), h * math.sin(decl), z


TURBULENCE_LEVELS = {"none": 0.0, "light": 0.5, "moderate": 1.5, "severe": 3.0}
"""Gust standard deviation [m/s] near the ground for the usual turbulence levels (MIL-F-8785C order of
magnitude at low altitude)."""


@dataclass(frozen=True)
class WindConfig:
    steady_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Mean wind vector (where the air moves to) in the world frame."""
    turbulence: float | str = 0.0
    """Gust strength: the standard deviation [m/s] on each horizontal axis, or a level name from
    :data:`TURBULENCE_LEVELS` ("none", "light", "moderate", "severe")."""
    turbulence_length_m: float = 50.0
    """Dryden scale length: gusts decorrelate after flying (or the wind carrying) this distance."""

    @property
    def turbulence_sigma_m_s(self) -> float:
        if isinstance(self.turbulence, str):
            return TURBULENCE_LEVELS[self.turbulence]
        return float(self.turbulence)

    def __post_init__(self) -> None:
        if isinstance(self.turbulence, str) and self.turbulence not in TURBULENCE_LEVELS:
            raise ScenarioError(
                f"wind: turbulence {self.turbulence!r} is not one of {sorted(TURBULENCE_LEVELS)} or a number"
            )
        if self.turbulence_sigma_m_s < 0 or self.turbulence_length_m <= 0:
            raise ScenarioError(
                f"wind: turbulence must be >= 0 and turbulence_length_m > 0, got {self.turbulence}, "
                f"{self.turbulence_length_m}"
            )


class Turbulence:
    """First-order Gauss-Markov gusts (the Dryden spectrum's low-order form), one seeded stream per vehicle.

    Each axis follows ``g' = -g/τ + σ·sqrt(2/τ)·w`` with τ = L / V, V the mean wind speed plus 1 m/s;
    the stationary standard deviation is σ.
    """

    def __init__(self, cfg: WindConfig, rng: np.random.Generator) -> None:
        self.cfg = cfg
        self.rng = rng
        self.gust = [0.0, 0.0, 0.0]
        speed = math.sqrt(sum(c * c for c in cfg.steady_ned_m_s)) + 1.0
        self.tau_s = cfg.turbulence_length_m / speed
        self._sigma = cfg.turbulence_sigma_m_s
        self._dt_s = math.nan
        self._ab = (0.0, 0.0)
        """(a, b) of the last ``dt_s`` (the tick is fixed: computed once)."""

    def step(self, dt_s: float) -> tuple[float, float, float]:
        """Advance by ``dt_s`` and return the wind (steady + gust) in NED [m/s]."""
        sigma = self._sigma
        w = self.cfg.steady_ned_m_s
        if sigma <= 0:
            return w
        if dt_s != self._dt_s:
            a = math.exp(-dt_s / self.tau_s)
            self._ab = (a, sigma * math.sqrt(1.0 - a * a))
            self._dt_s = dt_s
        a, b = self._ab
        z0, z1, z2 = self.rng.standard_normal(3).tolist()
        g = self.gust
        g0 = g[0] = a * g[0] + b * z0
        g1 = g[1] = a * g[1] + b * z1
        g2 = g[2] = a * g[2] + b * z2 * 0.5  # vertical gusts are weaker near the ground
        return w[0] + g0, w[1] + g1, w[2] + g2


class WorldChange(msgspec.Struct, array_like=True, frozen=True, tag="world"):
    """A change of one vehicle's simulated world asked for from its autopilot (ArduPilot's ``SIM_*``
    parameters; ``harness.autopilot.simworld``), applied by whoever steps its physics before the physics step
    that follows the tick ``t_ns`` (END-TICK-AC ``events``), and recorded. None: unchanged."""

    t_ns: int
    wind_ned_m_s: tuple[float, float, float] | None = None
    """The steady wind (where the air moves to)."""
    turbulence: float | None = None
    """Gust standard deviation [m/s]."""
    speedup: float | None = None
    """The run's pace (times real time; 0 as fast as possible): the run's, not the vehicle's."""

    def wind(self, before: WindConfig) -> WindConfig | None:
        """The wind after this change (None: unchanged)."""
        if self.wind_ned_m_s is None and self.turbulence is None:
            return None
        return WindConfig(
            steady_ned_m_s=self.wind_ned_m_s if self.wind_ned_m_s is not None else before.steady_ned_m_s,
            turbulence=self.turbulence if self.turbulence is not None else before.turbulence,
            turbulence_length_m=before.turbulence_length_m,
        )
