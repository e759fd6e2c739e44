"""What every world recorder records: a vehicle at a recorded tick (``WorldSink.vehicle``), and the kinds of
events (``WorldSink.event``)."""

from __future__ import annotations

import enum

import msgspec

from harness.core.geo import Quat, Vec3


class VehicleSample(msgspec.Struct, frozen=True):
    """One vehicle's ground truth and motor commands at sim time ``t_ns``."""

    t_ns: int
    vehicle: int
    pos_ned_m: Vec3
    quat_wxyz: Quat
    vel_ned_m_s: Vec3
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    motors: tuple[float, ...]
    on_ground: bool
    crashed: bool
    status: int = 0
    """The autopilot's END-TICK-AC status (``harness.wire.protocol.pack_status``: armed, landed state, PX4
    mode), so that a vehicle flown in another process still has its mode in the view."""


class WorldEvent(enum.StrEnum):
    """A run event in ``world.mcap``'s ``/events`` and the view's log (the value is what the files hold)."""

    PAUSED = "paused"
    RESUMED = "resumed"
    CRASH = "crash"
