"""The configuration of an autopilot process (``python -m harness.autopilot.sitl``) as one typed value.

``harness run`` and ``harness join`` write it as ``<run dir>/<name>.json`` and the process reads it with
``--config FILE``: what the launcher decided arrives as it was decided, with no argv round trip (the flags
remain for a process started by hand, and build the same value). A light module: the launcher imports it
without the flight stack.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import msgspec

from harness.autopilot.firmware import Firmware
from harness.core.files import read_child_config


@dataclass(frozen=True)
class AutopilotProcessConfig:
    """One autopilot process: what ``harness run`` / ``harness join`` write as ``<run dir>/<name>.json`` and
    the process reads with ``--config FILE`` (typed, no argv round trip); built from the flags when started by
    hand. Secrets never go here (the channel secret comes in the environment, the signing key from its file)."""

    address: str
    """The channel to join."""
    vehicles: tuple[int, ...]
    api_port_base: int = 14540
    """Send to this port + i (0: only to peers)."""
    api_local_port_base: int = 0
    """Listen on this port + i (0: any free port)."""
    gcs_port: int = 14550
    run_dir: str | None = None
    """Write ``vehicle-<i>.tlog`` (and the ULog, stored parameters) here."""
    params: dict[int, dict[str, float]] = field(default_factory=dict)
    """Parameter overrides by vehicle."""
    signing_key_file: str | None = None
    """MAVLink 2 signing: the file with the key as 64 hex digits."""
    trust_run: int = 0
    """With signing: obey unsigned frames from this pid's children (0: from nobody)."""
    ground_truth: bool = False
    firmware: tuple[Firmware, ...] = (Firmware.PX4,)
    """One for all, or one per vehicle."""
    tcp_port_base: int = 0
    """ArduPilot vehicles listen on TCP ``tcp_port_base + tcp_port_step * i``."""
    tcp_port_step: int = 1
    gcs_extra_ports: tuple[int, ...] = ()
    """Extra UDP outputs of ArduPilot vehicles."""
    tcp_sim_clients: bool = False
    """TCP clients are missions on sim time (a run)."""
    physics: str | None = None
    """Step these vehicles' physics here too, configured by this file (the run's ``physics.json``)."""
    name: str | None = None
    """This process's name in the channel."""

    def to_json(self) -> bytes:
        return msgspec.json.encode(self)

    @classmethod
    def read(cls, path: Path) -> AutopilotProcessConfig:
        """The configuration in ``path``; :class:`ScenarioError` when it cannot be read or is not one."""
        return read_child_config(path, cls, "an autopilot process configuration")
