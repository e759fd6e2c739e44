"""Where each firmware's own SITL puts its vehicles, and the environment PX4 SITL users set.

- ArduPilot SITL starts at CMAC (Canberra Model Aircraft Club: ``SIM_OPOS_LAT/LNG/ALT/HDG`` -35.363261,
  149.165230, 584 m, heading 353). Several instances (``sim_vehicle.py --count N``) all start there unless
  spread; the documented spread, ``--auto-offset-line 90,10``, puts instance i 10 i m east of the first
  (``sim_vehicle.py``: east = d sin(bearing), north = d cos(bearing), d = 10 i): the default here, so that
  vehicles never start inside each other.
- PX4 SITL starts at 47.397742, 8.545594, 488 m (Zurich, its worlds' and SIH's default), heading north, moved by
  the environment variables ``PX4_HOME_LAT``, ``PX4_HOME_LON``, ``PX4_HOME_ALT`` (each on its own; decimal
  degrees and metres); ``PX4_SIM_SPEED_FACTOR`` runs the simulation that many times faster than real time.

A run has one world origin: the firmware of vehicle 0 chooses it (a mixed run that wants another says so with
``[world]``); a scenario's ``[world]`` and ``spawn_ned_m`` win over these defaults.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from harness.autopilot.firmware import Firmware
from harness.core.errors import ScenarioError

Vec3 = tuple[float, float, float]

CMAC: Vec3 = (-35.363261, 149.165230, 584.0)
CMAC_HEADING_DEG = 353.0
ARDUPILOT_OFFSET_LINE = (90.0, 10.0)
"""(bearing deg, metres between instances): ``sim_vehicle.py --auto-offset-line 90,10``."""
PX4_HOME: Vec3 = (47.397742, 8.545594, 488.0)
PX4_HOME_ENV = ("PX4_HOME_LAT", "PX4_HOME_LON", "PX4_HOME_ALT")
PX4_SPEED_ENV = "PX4_SIM_SPEED_FACTOR"


def _env_number(env: Mapping[str, str], name: str) -> float | None:
    text = env.get(name)
    if text is None or not text.strip():
        return None
    try:
        x = float(text)
    except ValueError:
        raise ScenarioError(f"{name}: expected a number, got {text!r}") from None
    if not math.isfinite(x):
        raise ScenarioError(f"{name}: must be finite, got {text!r}")
    return x


def sitl_home(firmware: Firmware, env: Mapping[str, str]) -> Vec3:
    """(lat, lon, alt AMSL) where this firmware's SITL starts (PX4: with ``PX4_HOME_*`` from ``env``)."""
    if firmware is Firmware.ARDUPILOT:
        return CMAC
    lat, lon, alt = (_env_number(env, name) for name in PX4_HOME_ENV)
    home = (
        lat if lat is not None else PX4_HOME[0],
        lon if lon is not None else PX4_HOME[1],
        alt if alt is not None else PX4_HOME[2],
    )
    if not -90.0 < home[0] < 90.0 or not -180.0 <= home[1] <= 180.0:
        raise ScenarioError(f"PX4_HOME_LAT / PX4_HOME_LON: ({home[0]}, {home[1]}) is not a latitude/longitude")
    return home


def sitl_heading_deg(firmware: Firmware) -> float:
    """The heading the vehicle starts with (ArduPilot: ``SIM_OPOS_HDG``)."""
    return CMAC_HEADING_DEG if firmware is Firmware.ARDUPILOT else 0.0


def sitl_spawns(firmware: Firmware, count: int) -> tuple[Vec3, ...] | None:
    """Where ``count`` vehicles start relative to the origin; None: the physics' own grid (PX4)."""
    if firmware is not Firmware.ARDUPILOT:
        return None
    bearing, metres = ARDUPILOT_OFFSET_LINE
    b = math.radians(bearing)
    return tuple((round(i * metres * math.cos(b), 9), round(i * metres * math.sin(b), 9), 0.0) for i in range(count))


def sitl_speed(env: Mapping[str, str]) -> float | None:
    """``PX4_SIM_SPEED_FACTOR``, when set: the run's real-time factor."""
    x = _env_number(env, PX4_SPEED_ENV)
    if x is not None and not x > 0:
        raise ScenarioError(f"{PX4_SPEED_ENV}: must be > 0, got {env[PX4_SPEED_ENV]!r}")
    return x
