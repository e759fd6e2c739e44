"""The autopilot's PX4-dialect MAVLink interface (see docs/mavlink.md).

Layers: ``codec`` (frames, signing) -> ``transport`` (UDP links, peers) -> services (``heartbeat``,
``telemetry``, ``commands``, ``parameters``, ``mission``, ``offboard``) -> ``server`` (the wall-clock thread).
"""

from harness.autopilot.mavlink.codec import SigningConfig
from harness.autopilot.mavlink.server import MavlinkCounters, MavlinkServer
from harness.autopilot.mavlink.transport import PortsConfig

__all__ = ["MavlinkCounters", "MavlinkServer", "PortsConfig", "SigningConfig"]
