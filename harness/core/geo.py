"""The one 3-vector type and the geodesy every layer shares (flight stack, physics, network, recorder).

Two Earth radii, on purpose: the flight stack projects with the mean radius (as PX4's map projection),
the world model (``harness.fdm.environment``) and the recorder's map use the WGS-84 ellipsoid. Every
flat-earth offset goes through :func:`flat_offset_m` / :func:`flat_point` with the radius it means.
"""

from __future__ import annotations

import math
from typing import Final

Vec3 = tuple[float, float, float]
"""x, y, z (NED metres, m/s, rad/s …: the unit is in the name of the field that holds it)."""
Quat = tuple[float, float, float, float]
"""w, x, y, z; rotates body FRD to world NED."""

EARTH_RADIUS_M: Final = 6_371_000.0
"""Mean Earth radius (PX4's projection, the flight stack's flat-earth offsets, GPS noise)."""
WGS84_A_M: Final = 6378137.0
"""WGS-84 semi-major axis (the world model, the recorder's map)."""
WGS84_E2: Final = 6.69437999014e-3
"""WGS-84 first eccentricity squared."""


def quat_from_euler(roll: float, pitch: float, yaw: float) -> Quat:
    """The attitude of Euler angles (rad; roll, pitch, yaw as ZYX), as a unit quaternion."""
    cr, sr = math.cos(roll * 0.5), math.sin(roll * 0.5)
    cp, sp = math.cos(pitch * 0.5), math.sin(pitch * 0.5)
    cy, sy = math.cos(yaw * 0.5), math.sin(yaw * 0.5)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def flat_offset_m(
    lat0_deg: float, lon0_deg: float, lat_deg: float, lon_deg: float, radius_m: float = EARTH_RADIUS_M
) -> tuple[float, float]:
    """North and east metres from (lat0, lon0) to (lat, lon), flat earth around (lat0, lon0)."""
    return (
        math.radians(lat_deg - lat0_deg) * radius_m,
        math.radians(lon_deg - lon0_deg) * radius_m * math.cos(math.radians(lat0_deg)),
    )


def flat_point(
    lat0_deg: float, lon0_deg: float, north_m: float, east_m: float, radius_m: float = EARTH_RADIUS_M
) -> tuple[float, float]:
    """(lat, lon) ``north_m`` / ``east_m`` from (lat0, lon0): the inverse of :func:`flat_offset_m`."""
    coslat = max(math.cos(math.radians(lat0_deg)), 1e-6)
    return (
        lat0_deg + math.degrees(north_m / radius_m),
        lon0_deg + math.degrees(east_m / (radius_m * coslat)),
    )


class GeoRef:
    """Azimuthal equidistant projection around a reference point (as PX4's map projection)."""

    __slots__ = ("alt_m", "cos_lat", "lat_rad", "lon_rad", "sin_lat")

    def __init__(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> None:
        self.lat_rad = math.radians(lat_deg)
        self.lon_rad = math.radians(lon_deg)
        self.sin_lat = math.sin(self.lat_rad)
        self.cos_lat = math.cos(self.lat_rad)
        self.alt_m = alt_amsl_m

    def to_ned(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> Vec3:
        lat = math.radians(lat_deg)
        lon = math.radians(lon_deg)
        sin_lat, cos_lat = math.sin(lat), math.cos(lat)
        cos_d_lon = math.cos(lon - self.lon_rad)
        arg = self.sin_lat * sin_lat + self.cos_lat * cos_lat * cos_d_lon
        arg = -1.0 if arg < -1.0 else (1.0 if arg > 1.0 else arg)
        c = math.acos(arg)
        k = c / math.sin(c) if abs(c) > 1e-12 else 1.0
        north = k * (self.cos_lat * sin_lat - self.sin_lat * cos_lat * cos_d_lon) * EARTH_RADIUS_M
        east = k * cos_lat * math.sin(lon - self.lon_rad) * EARTH_RADIUS_M
        return (north, east, self.alt_m - alt_amsl_m)

    def to_geo(self, n: float, e: float, d: float) -> tuple[float, float, float]:
        x = n / EARTH_RADIUS_M
        y = e / EARTH_RADIUS_M
        c = math.sqrt(x * x + y * y)
        if c > 1e-12:
            sin_c, cos_c = math.sin(c), math.cos(c)
            lat = math.asin(cos_c * self.sin_lat + x * sin_c * self.cos_lat / c)
            lon = self.lon_rad + math.atan2(y * sin_c, c * self.cos_lat * cos_c - x * self.sin_lat * sin_c)
        else:
            lat, lon = self.lat_rad, self.lon_rad
        return (math.degrees(lat), math.degrees(lon), self.alt_m - d)
