"""What a run is asked to do: the validated plan a scenario file or the command line becomes.

:class:`LaunchPlan` is the scenario layer's product and the launcher's (``harness.run.launcher``) input; it
sits here, below both, so the scenario file model never imports the launcher.
"""

from __future__ import annotations

import enum
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from harness.autopilot.firmware import Firmware, firmware_of
from harness.core.endpoints import PX4_API_BASE
from harness.core.errors import ScenarioError
from harness.fdm.sensors import GpsProfile
from harness.net.model import NetworkKind
from harness.scenario.sitl_defaults import sitl_heading_deg, sitl_home, sitl_spawns


class AutopilotPlacement(enum.StrEnum):
    """Where a run's autopilots live."""

    IN_PROCESS = "in-process"
    """In the physics process with their MAVLink servers (no socket hop per tick)."""
    PROCESS = "process"
    """One SITL-like autopilot process for all vehicles, connected to the channel."""


@dataclass(frozen=True)
class MissionPlan:
    script: Path
    args: tuple[str, ...] = ()


@dataclass(frozen=True)
class LaunchPlan:
    """Everything a run needs, already validated (built from a scenario file or the command line)."""

    vehicles: int
    out: Path
    missions: tuple[MissionPlan | None, ...] = ()
    """Per vehicle (index i), or shorter: vehicles past the end fly no mission."""
    swarm_mission: MissionPlan | None = None
    """One script that commands every vehicle (``HARNESS_VEHICLES``; :mod:`harness.run.swarm`)."""
    remote_vehicles: int = 0
    """Vehicles ``vehicles …`` ``vehicles + remote_vehicles - 1``: physics here, flown by child channels that
    join on ``listen`` (``harness join``; :mod:`harness.run.tree`)."""
    listen: str | None = None
    """The root channel's address (default: a free loopback port); off loopback it needs ``secret``."""
    secret: bytes | None = None
    join_timeout_s: float = 600.0
    workers: int = 0
    """Processes that simulate the vehicles (physics and autopilots): this one and ``workers - 1`` autopilot
    hosts, each with an equal share of the vehicles (:func:`harness.run.tree.worker_groups`); 0 = auto, one
    per core with at least 2 vehicles each (:func:`harness.run.tree.auto_workers`)."""
    seed: int = 0
    physics_hz: float = 1000.0
    tick_hz: float = 250.0
    phase_every: int = 5
    speed: float | None = None
    """Real-time factor to pace at; None = as fast as possible."""
    duration_s: float | None = None
    network: NetworkKind = NetworkKind.NONE
    network_params: dict[str, Any] = field(default_factory=dict)
    stall_timeout_s: float = 30.0
    origin: tuple[float, float, float] | None = None
    """(lat, lon, alt AMSL) of the world; None: where vehicle 0's firmware's SITL starts (``sitl_defaults``: CMAC
    for ArduPilot, PX4's home or ``PX4_HOME_LAT/LON/ALT`` for PX4). Always set once the plan is built."""
    heading_deg: float | None = None
    """The vehicles' heading at the start; None: their SITL's (ArduPilot 353, PX4 0)."""
    wind_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    turbulence: float = 0.0
    gps: GpsProfile = GpsProfile.PX4_SITL
    """GPS error model."""
    sensor_noise: bool = True
    """False: ideal sensors (rates and latency stay)."""
    spawn_ned_m: tuple[tuple[float, float, float], ...] | None = None
    """Where each vehicle starts; None: as its SITL spaces several (ArduPilot: 10 m apart eastwards), PX4 on the
    physics' grid."""
    params: tuple[dict[str, float], ...] = ()
    api_port_base: int = PX4_API_BASE
    """Vehicle ``i`` listens for its mission on UDP ``api_port_base + i`` (PX4 SITL's 14580 + i when free)."""
    gcs_port: int | None = None
    """Where the vehicles send to a ground station (a destination: listened on or not). None: a port of the run's
    own (a batch run: nothing outside the run hears or commands its vehicles); ``harness sitl``: 14550; 0: off."""
    api_remote_base: int = 0
    """Vehicle ``i`` also sends to UDP ``api_remote_base + i`` unasked (``harness sitl``: 14540, where hand-run
    MAVSDK scripts listen); 0 = only to the peers that spoke to it (``harness run``: its own missions)."""
    record_hz: float = 50.0
    pause_at_s: float | None = None
    """Stand the clock still once sim time reaches this, for ``pause_wall_s`` of wall time (stall tests)."""
    pause_wall_s: float = 5.0
    autopilots: AutopilotPlacement = AutopilotPlacement.IN_PROCESS
    progress: Callable[[str], None] | None = None
    firmware: tuple[Firmware, ...] = ()
    """Per vehicle (or one entry for all; empty: PX4): the personality its MAVLink side presents."""
    tcp_port_base: int | None = None
    """ArduPilot vehicles' SERIAL0 (TCP) ports: ``tcp_port_base + tcp_port_step * i``; None: the run's own
    block (vehicle i listens on TCP ``api_port_base + i``, the number of its UDP API port)."""
    tcp_port_step: int = 1
    gcs_extra_ports: tuple[int, ...] = ()
    """More UDP outputs of ArduPilot vehicles (``harness sitl``: 14551, beside the GCS port 14550)."""
    mission_stdin: bool = False
    """The terminal's stdin to the run's one mission, its output shown here as well (``harness run --stdin``:
    prompt-driven scripts); otherwise a mission's stdin is at end-of-file from the start."""
    signing_key_file: Path | None = None
    """MAVLink 2 signing on every link (64 hex characters in the file): unsigned frames are obeyed only from this
    run's own processes (``docs/mavlink.md``, "Signing")."""

    def __post_init__(self) -> None:
        # the command line and ``--set`` give the kinds as text: one clear error for a bad one
        for name, kind in (("network", NetworkKind), ("autopilots", AutopilotPlacement), ("gps", GpsProfile)):
            value = getattr(self, name)
            try:
                object.__setattr__(self, name, kind(value))
            except ValueError:
                choices = ", ".join(repr(k.value) for k in kind)
                raise ScenarioError(f"{name}: expected one of {choices}, got {value!r}") from None
        first = self.firmware_of(0)
        if self.origin is None:
            object.__setattr__(self, "origin", sitl_home(first, os.environ))
        if self.heading_deg is None:
            object.__setattr__(self, "heading_deg", sitl_heading_deg(first))
        if self.spawn_ned_m is None:
            object.__setattr__(self, "spawn_ned_m", sitl_spawns(first, self.vehicles + self.remote_vehicles))

    @property
    def world_origin(self) -> tuple[float, float, float]:
        """``origin``, resolved (never None once built)."""
        assert self.origin is not None
        return self.origin

    def firmware_of(self, vehicle: int) -> Firmware:
        return firmware_of(self.firmware, vehicle)

    view_port: int | None = None
    """Serve the run's 3D view (``world.rrd``'s stream) live to Rerun viewers on this loopback gRPC port."""
    on_view: Callable[[str], None] | None = None
    """Called with the live view's address (``rerun+http://…``) once it serves, before the simulation starts."""
