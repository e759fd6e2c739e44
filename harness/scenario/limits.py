"""The bounds every run setting must be within, checked before anything starts (``docs/scenario.md``, "Limits").

One check per field, one :class:`ScenarioError` line naming the field as the user wrote it (``rates.tick_hz``
in a scenario file, ``--vehicles`` on the command line) — never a traceback, never a run that starts and then
fails on a value that was wrong from the beginning. :func:`check_plan` runs on every :class:`LaunchPlan`:
from a scenario file (the loader passes its field names), from the command line, and in ``Launcher``.

The numbers and why:

- **vehicles** ≤ :data:`MAX_VEHICLES` = 244: vehicle i is MAVLink system id i + 1, and 245 (MAVSDK) and
  255 (QGroundControl, MAVProxy, pymavlink) are the ground stations' ids. And the run must fit in the
  machine's available memory (``MemAvailable``), estimated from measurements (:func:`memory_estimate_mb`).
- **ports**: 1024–65535 (below 1024 only as root), the whole block (``api_port_base + vehicles - 1``,
  ``tcp_port_base + step × (vehicles - 1)``) too; a GCS port of 0 turns that link off.
- **rates**: ``physics_hz`` 10–100 000 Hz, ``tick_hz`` 1 Hz up to ``physics_hz``, a phase period
  (``phase_every / tick_hz``) of at most 10 s.
- **durations**: finite and > 0; ``duration_s`` at least one tick and at most 10⁹ s (sim time is an int64 of
  nanoseconds); watchdog and pause times at most a day (86 400 s).
- **world**: latitude ±90°, longitude ±180°, altitude −500–10 000 m; wind components ±100 m/s, turbulence
  0–30 m/s; every vehicle starts within 100 km of the origin (and 1 km up or down).
- **vehicle parameters**: known names, values within each parameter's range (what the autopilot enforces).
- **network parameters**: the keys and values the chosen model declares (``RadioConfig`` / ``Ns3Config``),
  checked here without importing ns-3.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from harness.core.errors import ScenarioError

if TYPE_CHECKING:
    from harness.scenario.plan import LaunchPlan

MAX_VEHICLES = 244
MAX_DURATION_S = 1e9
MAX_WAIT_S = 86_400.0
PHYSICS_HZ = (10.0, 100_000.0)
MAX_PHASE_PERIOD_S = 10.0
MAX_SPAWN_M = 100_000.0

BASE_MB = 140
"""``harness run`` itself (Python, JSBSim, recorder) with one vehicle: 131 MB peak RSS measured."""
PER_VEHICLE_MB = 2
"""Each more vehicle in the run's process (JSBSim instance, autopilot, MAVLink server): 0.8 MB measured."""
PER_MISSION_MB = 80
"""A mission process: 53 MB for a MAVSDK script plus 21 MB for its ``mavsdk_server`` (measured)."""
NETWORK_MB = 80
"""The network process (built-in model; ns-3 takes more)."""


def memory_estimate_mb(vehicles: int, missions: int, network: bool) -> int:
    """Resident memory a run needs, from the measurements above (``docs/scenario.md``)."""
    return BASE_MB + PER_VEHICLE_MB * vehicles + PER_MISSION_MB * missions + (NETWORK_MB if network else 0)


def available_memory_mb() -> int | None:
    """``MemAvailable`` of ``/proc/meminfo`` in MB; None where there is no such file."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) // 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def lowest_port() -> int:
    """Ports below 1024 need root."""
    return 1 if os.geteuid() == 0 else 1024


def vehicle_count_error(n: object) -> str | None:
    """What is wrong with ``n`` as a vehicle count, or None (the scenario loader asks before laying them out)."""
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_VEHICLES:
        return f"must be 1-{MAX_VEHICLES} (vehicle i is MAVLink system id i + 1; 245 and 255 are ground stations), got {n!r}"
    return None


class _Checker:
    def __init__(self, prefix: str, names: Mapping[str, str]) -> None:
        self.prefix = prefix
        self.names = names

    def fail(self, field: str, why: str) -> ScenarioError:
        return ScenarioError(f"{self.prefix}{self.names.get(field, field)}: {why}")

    def number(self, value: Any, field: str, lo: float, hi: float, *, lo_open: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.fail(field, f"must be a finite number, got {value!r}")
        if value > hi or value < lo or (lo_open and value == lo):
            low = f"> {lo:g}" if lo_open else f">= {lo:g}"
            raise self.fail(field, f"must be {low} and <= {hi:g}, got {value!r}")
        return float(value)

    def port_block(self, field: str, base: int, count: int, step: int = 1, *, zero_ok: bool = False) -> None:
        if zero_ok and base == 0:
            return
        lo = lowest_port()
        last = base + step * (count - 1)
        if isinstance(base, bool) or not isinstance(base, int) or base < lo or base > 65535:
            why = f"must be a port number {lo}-65535" + (" (or 0: off)" if zero_ok else "")
            root = " (ports below 1024 need root)" if isinstance(base, int) and 0 < base < lo else ""
            raise self.fail(field, f"{why}, got {base!r}{root}")
        if last > 65535:
            raise self.fail(field, f"{base} + {count - 1} more ports goes past 65535 (to {last}) for {count} vehicles")


def check_plan(plan: LaunchPlan, prefix: str = "", names: Mapping[str, str] | None = None) -> None:
    """Raise one ScenarioError line for the first setting out of its bounds; ``names`` maps a plan field to
    the name the user gave it (``{"tick_hz": "rates.tick_hz"}``), ``prefix`` names the file."""
    c = _Checker(prefix, names or {})
    n = plan.vehicles
    if any("SIM_SPEEDUP" in p for p in plan.params):  # one pace for the run: ``speed`` (SIM_SPEEDUP shows it)
        raise c.fail("params", "SIM_SPEEDUP is the run's pace: give it as speed (or --speed); it reads it")
    why = vehicle_count_error(n)
    if why is not None:
        raise c.fail("vehicles", why)
    missions = sum(1 for m in plan.missions[:n] if m is not None)
    need, have = memory_estimate_mb(n, missions, plan.network != "none"), available_memory_mb()
    if have is not None and need > have:
        raise c.fail(
            "vehicles",
            f"{n} vehicles with {missions} missions need about {need} MB of memory, the machine has {have} MB available",
        )
    if isinstance(plan.seed, bool) or not isinstance(plan.seed, int) or not 0 <= plan.seed < 2**63:
        raise c.fail("seed", f"must be an integer 0 to 2**63-1, got {plan.seed!r}")
    physics = c.number(plan.physics_hz, "physics_hz", *PHYSICS_HZ)
    tick = c.number(plan.tick_hz, "tick_hz", 1.0, physics)
    if not isinstance(plan.phase_every, int) or plan.phase_every < 1:
        raise c.fail("phase_every", f"must be an integer >= 1, got {plan.phase_every!r}")
    if plan.phase_every / tick > MAX_PHASE_PERIOD_S:
        raise c.fail(
            "phase_every",
            f"{plan.phase_every} ticks at {tick:g} Hz is a phase period over {MAX_PHASE_PERIOD_S:g} s",
        )
    c.number(plan.record_hz, "record_hz", 0.0, 1e6, lo_open=True)  # above tick_hz: every tick is recorded
    if plan.speed is not None:
        c.number(plan.speed, "speed", 0.0, 1e6, lo_open=True)
    if plan.duration_s is not None:
        c.number(plan.duration_s, "duration_s", 1.0 / tick, MAX_DURATION_S)
    c.number(plan.stall_timeout_s, "stall_timeout_s", 0.0, MAX_WAIT_S, lo_open=True)
    if plan.pause_at_s is not None:
        c.number(plan.pause_at_s, "pause_at_s", 0.0, MAX_DURATION_S)
    c.number(plan.pause_wall_s, "pause_wall_s", 0.0, MAX_WAIT_S, lo_open=True)
    for i, (field, lo, hi) in enumerate((("lat_deg", -90, 90), ("lon_deg", -180, 180), ("alt_amsl_m", -500, 10_000))):
        c.number(plan.world_origin[i], field, lo, hi)
    for i, axis in enumerate(("north_m_s", "east_m_s", "down_m_s")):
        c.number(plan.wind_ned_m_s[i], axis, -100.0, 100.0)
    c.number(plan.turbulence, "turbulence", 0.0, 30.0)
    c.port_block("api_port_base", plan.api_port_base, n)
    if plan.gcs_port is not None:
        c.port_block("gcs_port", plan.gcs_port, 1, zero_ok=True)
    c.port_block("api_remote_base", plan.api_remote_base, n, zero_ok=True)
    if plan.tcp_port_base is not None:
        if not isinstance(plan.tcp_port_step, int) or plan.tcp_port_step < 1:
            raise c.fail("tcp_port_step", f"must be an integer >= 1, got {plan.tcp_port_step!r}")
        c.port_block("tcp_port_base", plan.tcp_port_base, n, plan.tcp_port_step)
    for port in plan.gcs_extra_ports:
        c.port_block("gcs_extra_ports", port, 1)
    if plan.view_port is not None:
        c.port_block("view_port", plan.view_port, 1)
    if plan.autopilots not in ("in-process", "process"):
        raise c.fail("autopilots", f"must be 'in-process' or 'process', got {plan.autopilots!r}")
    check_spawns(plan, c)
    check_params(plan, c)
    check_network(plan.network, plan.network_params, c)
    if plan.signing_key_file is not None:
        from harness.core.secrets import read_signing_key

        read_signing_key(plan.signing_key_file, f"{prefix}{c.names.get('signing_key_file', 'signing_key_file')}")


def check_spawns(plan: LaunchPlan, c: _Checker) -> None:
    for i, spawn in enumerate(plan.spawn_ned_m or ()):
        if (
            not all(math.isfinite(x) for x in spawn)
            or math.hypot(spawn[0], spawn[1]) > MAX_SPAWN_M
            or abs(spawn[2]) > 1000
        ):
            raise c.fail(
                "spawn_ned_m",
                f"vehicle {i} would start at {spawn} m, more than {MAX_SPAWN_M / 1000:g} km from the origin "
                "or 1 km above or below it",
            )


def check_params(plan: LaunchPlan, c: _Checker) -> None:
    """Each vehicle's parameter overrides: known names, values in their ranges (as the autopilot applies them)."""
    from harness.autopilot.firmware import firmware_of
    from harness.autopilot.mavlink.personality import core_param_defaults
    from harness.autopilot.params import Params

    checked: set[tuple[str, frozenset[tuple[str, float]]]] = set()
    for i, overrides in enumerate(plan.params[: plan.vehicles]):
        fw = firmware_of(plan.firmware, i)
        key = (fw.value, frozenset(overrides.items()))
        if not overrides or key in checked:
            continue
        checked.add(key)
        try:
            Params(overrides={**core_param_defaults(fw), **overrides})
        except ScenarioError as exc:
            raise c.fail("params", f"vehicle {i}: {exc}") from None


def check_network(model: str, params: Mapping[str, object], c: _Checker) -> None:
    """The model's own parameter check (the one the network process runs), here before anything starts."""
    if model not in ("none", "builtin", "ns3"):
        raise c.fail("network", f"must be 'builtin', 'ns3' or 'none', got {model!r}")
    try:
        if model == "builtin":
            from harness.net.builtin import RadioConfig

            RadioConfig.from_params(params)
        elif model == "ns3":
            from harness.net.ns3model import Ns3Config  # the configuration only: ns-3 itself is not imported

            Ns3Config.from_params(params)
    except ScenarioError as exc:
        raise ScenarioError(f"{c.prefix}{exc}") from None
