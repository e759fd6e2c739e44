"""Scenario files (TOML): validated into a :class:`~harness.run.launcher.LaunchPlan`.

Every error is a :class:`ScenarioError` whose message is one line naming the file, the field and what is
wrong (``scenario.toml: vehicles[1].mission: file missions/x.py does not exist``). Unknown keys get the
closest valid name suggested. Paths in the file are relative to the file's directory.

Reference: ``docs/scenario.md``.
"""

from __future__ import annotations

import copy
import difflib
import math
import os
import re
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from harness.autopilot.firmware import Firmware, firmware_of
from harness.core.errors import ScenarioError
from harness.core.files import read_text, script_file
from harness.core.limits import cut, depth, shown
from harness.fdm.sensors import GPS_PROFILES, GpsProfile, gps_profile_names
from harness.net.model import NetworkKind
from harness.scenario.limits import check_plan, vehicle_count_error
from harness.scenario.plan import LaunchPlan, MissionPlan
from harness.scenario.sitl_defaults import sitl_home

_TOP = {
    "seed",
    "speed",
    "duration_s",
    "out",
    "world",
    "rates",
    "wind",
    "sensors",
    "network",
    "vehicles",
    "channel",
    "mavlink",
    "swarm",
}
_SECTIONS: dict[str, set[str]] = {
    "world": {"lat_deg", "lon_deg", "alt_amsl_m"},
    "rates": {"physics_hz", "tick_hz", "phase_every"},
    "wind": {"north_m_s", "east_m_s", "down_m_s", "turbulence"},
    "sensors": {"gps", "noise"},
    "network": {"model", "params"},
    "channel": {"stall_timeout_s"},
    "mavlink": {"api_port_base", "gcs_port", "signing_key_file"},
    "swarm": {"mission", "args"},
}
MAX_SCENARIO_BYTES = 1 << 20
"""A scenario file is a few kB; one of more than a MiB is refused before it is parsed."""
MAX_DEPTH = 16
"""Tables and arrays nest at most this deep (``vehicles[1].params`` is 3)."""
_VEHICLES_TABLE = {"count", "mission", "args", "spawn", "spacing_m", "params", "firmware"}
_VEHICLE = {"mission", "args", "spawn_ned_m", "params", "firmware"}
_SPAWNS = {"grid", "line", "circle"}


class _Ctx:
    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, field: str, why: str) -> ScenarioError:
        """The error, one line: what the user wrote appears cut (``limits.cut``), however long it was."""
        return ScenarioError(f"{self.path}: {cut(field)}: {why}")

    def keys(self, table: Mapping[str, Any], allowed: set[str], where: str) -> None:
        for key in table:
            if key not in allowed:
                close = difflib.get_close_matches(key, sorted(allowed), n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else f" (valid: {', '.join(sorted(allowed))})"
                raise self.fail(f"{where}{key}", f"unknown key{hint}")

    def number(self, value: Any, field: str, *, positive: bool = False, minimum: float | None = None) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(field, f"expected a number, got {type(value).__name__} {shown(value)}")
        x = float(value)
        if not math.isfinite(x):
            raise self.fail(field, f"must be finite, got {shown(value)}")
        if positive and not x > 0:
            raise self.fail(field, f"must be > 0, got {shown(value)}")
        if minimum is not None and x < minimum:
            raise self.fail(field, f"must be >= {minimum:g}, got {shown(value)}")
        return x

    def integer(self, value: Any, field: str, *, minimum: int | None = None) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(field, f"expected an integer, got {type(value).__name__} {shown(value)}")
        if minimum is not None and value < minimum:
            raise self.fail(field, f"must be >= {minimum}, got {shown(value)}")
        return value

    def count(self, value: Any, field: str) -> int:
        """A vehicle count, refused before anything is laid out for it (``limits.py``)."""
        n = self.integer(value, field, minimum=1)
        why = vehicle_count_error(n)
        if why is not None:
            raise self.fail(field, why)
        return n

    def table(self, value: Any, field: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(field, f"expected a table, got {type(value).__name__}")
        return value

    def mission(self, value: Any, field: str) -> Path:
        if not isinstance(value, str) or not value:
            raise self.fail(field, f"expected the path of a script, got {shown(value)}")
        path = (self.path.parent / value).resolve()
        if not path.exists():
            raise self.fail(field, f"file {cut(value)} does not exist (looked in {cut(str(path.parent))})")
        try:
            return script_file(path, "the script")
        except ScenarioError as exc:
            raise self.fail(field, str(exc)) from None

    def file_path(self, value: Any, field: str) -> Path:
        """A path given in the file, relative to the file's directory."""
        if not isinstance(value, str) or not value:
            raise self.fail(field, f"expected a path, got {shown(value)}")
        return (self.path.parent / value).resolve()

    def args(self, value: Any, field: str) -> tuple[str, ...]:
        if not isinstance(value, list) or not all(isinstance(a, str | int | float) for a in value):
            raise self.fail(field, f"expected a list of strings, got {shown(value)}")
        return tuple(str(a) for a in value)

    def params(self, value: Any, field: str) -> dict[str, float]:
        table = self.table(value, field)
        return {str(k): self.number(v, f"{field}.{k}") for k, v in table.items()}

    def vec3(self, value: Any, field: str) -> tuple[float, float, float]:
        if not isinstance(value, list) or len(value) != 3:
            raise self.fail(field, f"expected [north, east, down] in metres, got {shown(value)}")
        n, e, d = (self.number(v, f"{field}[{i}]") for i, v in enumerate(value))
        return (n, e, d)


def _spawn_layout(kind: str, count: int, spacing: float) -> tuple[tuple[float, float, float], ...]:
    if kind == "line":
        return tuple((0.0, i * spacing, 0.0) for i in range(count))
    if kind == "circle":
        radius = max(spacing, spacing * count / (2 * math.pi))
        return tuple(
            (radius * math.cos(2 * math.pi * i / count), radius * math.sin(2 * math.pi * i / count), 0.0)
            for i in range(count)
        )
    cols = max(1, math.ceil(math.sqrt(count)))
    return tuple((-(i // cols) * spacing, (i % cols) * spacing, 0.0) for i in range(count))


def parse_value(text: str) -> Any:
    """A value given on the command line (``--set path=VALUE``): a TOML value (``4``, ``2.5``, ``true``,
    ``"x"``, ``[0, 0, 0]``, ``{ A = 1 }``), else the text itself as a string (``--set sensors.gps=standalone``)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


_SEGMENT = re.compile(r"^([A-Za-z_][A-Za-z0-9_-]*)(?:\[(\d+)\])?$")


def set_path(raw: dict[str, Any], dotted: str, value: Any) -> None:
    """Set ``dotted`` (``wind.north_m_s``, ``network.params.bit_rate_bps``, ``vehicles[1].params.X``) in the
    parsed TOML ``raw``, creating missing tables. Whether the key is valid is for the loader to say."""
    parts = dotted.split(".")
    node: Any = raw
    walked = ""
    for n, part in enumerate(parts):
        m = _SEGMENT.match(part)
        if m is None:
            raise ScenarioError(f"--set {dotted}: {shown(part)} is not a key (expected name or name[index])")
        key, index = m.group(1), m.group(2)
        walked = f"{walked}.{key}" if walked else key
        last = n == len(parts) - 1
        if not isinstance(node, dict):
            raise ScenarioError(f"--set {dotted}: {walked.rsplit('.', 1)[0]} is not a table in the scenario")
        if index is None:
            if last:
                node[key] = value
            else:
                node = node.setdefault(key, {})
            continue
        items = node.get(key)
        if not isinstance(items, list) or not int(index) < len(items):
            size = len(items) if isinstance(items, list) else 0
            raise ScenarioError(f"--set {dotted}: {walked} has {size} entries in the scenario, no [{index}]")
        walked += f"[{index}]"
        if last:
            items[int(index)] = value
        else:
            node = items[int(index)]


def load_scenario(path: str | Path, sets: Sequence[tuple[str, Any]] = (), **overrides: Any) -> LaunchPlan:
    """Read and validate a scenario file; ``sets`` (dotted path, value) are applied to the file's contents
    before validation (``--set``), ``overrides`` (from the command line) win over the file."""
    path = Path(path)
    ctx = _Ctx(path)
    text = read_text(path, "scenario file", max_bytes=MAX_SCENARIO_BYTES)
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {cut(str(exc), 200)}") from None
    except RecursionError:  # tomllib recurses per level of nesting
        raise ScenarioError(f"{path}: nested deeper than {MAX_DEPTH} levels (a scenario nests 3 or 4)") from None
    if depth(raw, MAX_DEPTH) > MAX_DEPTH:
        raise ScenarioError(f"{path}: nested deeper than {MAX_DEPTH} levels (a scenario nests 3 or 4)")
    if sets:
        raw = copy.deepcopy(raw)
        for dotted, value in sets:
            set_path(raw, dotted, value)
    ctx.keys(raw, _TOP, "")
    for name, allowed in _SECTIONS.items():
        if name in raw:
            ctx.keys(ctx.table(raw[name], name), allowed, f"{name}.")
    world = raw.get("world", {})
    rates = raw.get("rates", {})
    wind = raw.get("wind", {})
    sensors = raw.get("sensors", {})
    net = raw.get("network", {})
    channel = raw.get("channel", {})
    mav = raw.get("mavlink", {})
    team = raw.get("swarm", {})
    if team and "mission" not in team:
        raise ctx.fail("swarm.mission", "missing: the [swarm] table needs the script that commands every vehicle")

    speed: float | None = None
    if "speed" in raw:
        if raw["speed"] == "max":
            speed = None
        else:
            speed = ctx.number(raw["speed"], "speed", positive=True)
    physics_hz = ctx.number(rates.get("physics_hz", 1000.0), "rates.physics_hz", positive=True)
    tick_hz = ctx.number(rates.get("tick_hz", 250.0), "rates.tick_hz", positive=True)
    ratio = physics_hz / tick_hz
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise ctx.fail(
            "rates.physics_hz", f"must be a whole multiple of rates.tick_hz ({tick_hz:g}), got {physics_hz:g}"
        )
    model = net.get("model", "none")
    if model not in set(NetworkKind):
        raise ctx.fail("network.model", f"must be 'builtin', 'ns3' or 'none', got {shown(model)}")

    missions, spawns, params = _vehicles(ctx, raw.get("vehicles"))
    firmware = _firmwares(ctx, raw.get("vehicles"), len(missions))
    fields: dict[str, Any] = dict(
        vehicles=len(missions),
        out=Path(str(raw.get("out", "runs/" + path.stem))),
        missions=tuple(missions),
        swarm_mission=(
            MissionPlan(ctx.mission(team["mission"], "swarm.mission"), ctx.args(team.get("args", []), "swarm.args"))
            if "mission" in team
            else None
        ),
        seed=ctx.integer(raw.get("seed", 0), "seed", minimum=0),
        physics_hz=physics_hz,
        tick_hz=tick_hz,
        phase_every=ctx.integer(rates.get("phase_every", 5), "rates.phase_every", minimum=1),
        speed=speed,
        duration_s=ctx.number(raw["duration_s"], "duration_s", positive=True) if "duration_s" in raw else None,
        network=NetworkKind(model),
        network_params=dict(ctx.table(net.get("params", {}), "network.params")),
        stall_timeout_s=ctx.number(channel.get("stall_timeout_s", 30.0), "channel.stall_timeout_s", positive=True),
        wind_ned_m_s=(
            ctx.number(wind.get("north_m_s", 0.0), "wind.north_m_s"),
            ctx.number(wind.get("east_m_s", 0.0), "wind.east_m_s"),
            ctx.number(wind.get("down_m_s", 0.0), "wind.down_m_s"),
        ),
        turbulence=_turbulence(ctx, wind.get("turbulence", 0.0)),
        gps=_gps_profile(ctx, sensors.get("gps", "px4-sitl")),
        sensor_noise=_boolean(ctx, sensors.get("noise", True), "sensors.noise"),
        spawn_ned_m=spawns,
        params=tuple(params),
        firmware=firmware,
        api_port_base=ctx.integer(mav.get("api_port_base", 14580), "mavlink.api_port_base", minimum=1),
        gcs_port=ctx.integer(mav["gcs_port"], "mavlink.gcs_port", minimum=0) if "gcs_port" in mav else None,
        signing_key_file=ctx.file_path(mav["signing_key_file"], "mavlink.signing_key_file")
        if "signing_key_file" in mav
        else None,
    )
    fields.update({k: v for k, v in overrides.items() if v is not None})
    if world:  # what the file gives; the rest where vehicle 0's firmware's SITL starts
        home = sitl_home(firmware_of(fields["firmware"], 0), os.environ)
        fields["origin"] = tuple(
            ctx.number(world.get(key, home[i]), f"world.{key}", minimum=lo)
            for i, (key, lo) in enumerate((("lat_deg", -90), ("lon_deg", -180), ("alt_amsl_m", None)))
        )
    plan = LaunchPlan(**fields)
    check_plan(plan, f"{path}: ", _PLAN_NAMES)
    return plan


_PLAN_NAMES = {
    "physics_hz": "rates.physics_hz",
    "tick_hz": "rates.tick_hz",
    "phase_every": "rates.phase_every",
    "stall_timeout_s": "channel.stall_timeout_s",
    "lat_deg": "world.lat_deg",
    "lon_deg": "world.lon_deg",
    "alt_amsl_m": "world.alt_amsl_m",
    "north_m_s": "wind.north_m_s",
    "east_m_s": "wind.east_m_s",
    "down_m_s": "wind.down_m_s",
    "turbulence": "wind.turbulence",
    "network": "network.model",
    "api_port_base": "mavlink.api_port_base",
    "gcs_port": "mavlink.gcs_port",
    "tcp_port_base": "--tcp-port-base",
    "view_port": "--view-port",
    "signing_key_file": "mavlink.signing_key_file",
    "params": "vehicles.params",
    "spawn_ned_m": "vehicles",
}
"""The scenario file's name of a LaunchPlan field, for error messages (the rest have the same name)."""


def _gps_profile(ctx: _Ctx, value: Any) -> GpsProfile:
    if value not in GPS_PROFILES:
        raise ctx.fail("sensors.gps", f"expected one of {gps_profile_names()}, got {shown(value)}")
    return GpsProfile(value)


def _boolean(ctx: _Ctx, value: Any, field: str) -> bool:
    if not isinstance(value, bool):
        raise ctx.fail(field, f"expected true or false, got {type(value).__name__} {shown(value)}")
    return value


def _turbulence(ctx: _Ctx, value: Any) -> float:
    from harness.fdm.environment import TURBULENCE_LEVELS

    if isinstance(value, str):
        if value not in TURBULENCE_LEVELS:
            raise ctx.fail(
                "wind.turbulence", f"expected a number or one of {sorted(TURBULENCE_LEVELS)}, got {shown(value)}"
            )
        return TURBULENCE_LEVELS[value]
    return ctx.number(value, "wind.turbulence", minimum=0)


def _vehicles(
    ctx: _Ctx, raw: Any
) -> tuple[list[MissionPlan | None], tuple[tuple[float, float, float], ...] | None, list[dict[str, float]]]:
    if raw is None:
        raise ctx.fail("vehicles", "missing: give vehicles = N, a [vehicles] table with count, or [[vehicles]] entries")
    if isinstance(raw, bool | int):
        count = ctx.count(raw, "vehicles")
        return [None] * count, None, [{}] * count
    if isinstance(raw, dict):
        ctx.keys(raw, _VEHICLES_TABLE, "vehicles.")
        count = ctx.count(raw.get("count", 1), "vehicles.count")
        mission = (
            MissionPlan(ctx.mission(raw["mission"], "vehicles.mission"), ctx.args(raw.get("args", []), "vehicles.args"))
            if "mission" in raw
            else None
        )
        layout = raw.get("spawn", "grid")
        if layout not in _SPAWNS:
            raise ctx.fail("vehicles.spawn", f"must be one of {sorted(_SPAWNS)}, got {shown(layout)}")
        spacing = ctx.number(raw.get("spacing_m", 5.0), "vehicles.spacing_m", positive=True)
        shared = ctx.params(raw.get("params", {}), "vehicles.params")
        given = "spawn" in raw or "spacing_m" in raw  # else: as the firmware's SITL spaces them
        return [mission] * count, _spawn_layout(layout, count, spacing) if given else None, [shared] * count
    if isinstance(raw, list):
        if not raw:
            raise ctx.fail("vehicles", "the list is empty: a run needs at least one vehicle")
        ctx.count(len(raw), "vehicles")
        missions: list[MissionPlan | None] = []
        spawns: list[tuple[float, float, float]] = []
        per_vehicle: list[dict[str, float]] = []
        defaults = _spawn_layout("grid", len(raw), 5.0)
        for i, entry in enumerate(raw):
            where = f"vehicles[{i}]"
            table = ctx.table(entry, where)
            ctx.keys(table, _VEHICLE, f"{where}.")
            missions.append(
                MissionPlan(
                    ctx.mission(table["mission"], f"{where}.mission"), ctx.args(table.get("args", []), f"{where}.args")
                )
                if "mission" in table
                else None
            )
            spawns.append(
                ctx.vec3(table["spawn_ned_m"], f"{where}.spawn_ned_m") if "spawn_ned_m" in table else defaults[i]
            )
            per_vehicle.append(ctx.params(table.get("params", {}), f"{where}.params"))
        given = any("spawn_ned_m" in t for t in raw if isinstance(t, dict))
        return missions, tuple(spawns) if given else None, per_vehicle
    raise ctx.fail("vehicles", f"expected a count, a table or a list of tables, got {type(raw).__name__}")


def _firmwares(ctx: _Ctx, raw: Any, count: int) -> tuple[Firmware, ...]:
    """``firmware = "px4" | "ardupilot"`` in the [vehicles] table (all) or in each [[vehicles]] entry."""
    if isinstance(raw, dict):
        return (Firmware.parse(raw.get("firmware", "px4"), f"{ctx.path}: vehicles.firmware"),) * count
    if isinstance(raw, list):
        return tuple(
            Firmware.parse(t.get("firmware", "px4"), f"{ctx.path}: vehicles[{i}].firmware")
            for i, t in enumerate(raw)
            if isinstance(t, dict)
        )
    return ()
