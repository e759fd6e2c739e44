"""What every world recorder records: a vehicle at a recorded tick (``WorldSink.vehicle``), and the kinds of
events (``WorldSink.event``)."""

from __future__ import annotations

import enum
import math
from typing import Any

import msgspec

from harness.autopilot.camera import Capture
from harness.autopilot.mathutil import quat_to_euler
from harness.core.geo import Quat, Vec3, quat_from_euler
from harness.wire.protocol import unpack_gimbal


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
    mode, the gimbal's attitude once one was used), so that a vehicle flown in another process still has its
    mode and gimbal in the recordings."""


class GimbalSample(msgspec.Struct, frozen=True):
    """A vehicle's gimbal at a recorded tick, as PX4's gimbal device reports it (pitch earth-stabilised,
    yaw in the vehicle frame, roll held level) and composed with the vehicle's true heading."""

    pitch_deg: float
    yaw_deg: float
    """Relative to the vehicle's heading (GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME)."""
    heading_deg: float
    """The camera's yaw from north: the vehicle's true heading plus ``yaw_deg``, in [-180, 180)."""
    quat_wxyz: Quat
    """The camera's attitude in the world NED frame (x along the optical axis): yaw ``heading_deg``, then
    pitch ``pitch_deg``, roll 0."""


def gimbal_of(s: VehicleSample) -> GimbalSample | None:
    """The gimbal ``s.status`` carries (None for a vehicle whose gimbal nobody used, or without one)."""
    att = unpack_gimbal(s.status)
    if att is None:
        return None
    pitch, yaw = att
    body_yaw = math.degrees(quat_to_euler(s.quat_wxyz)[2])
    heading = (body_yaw + yaw + 180.0) % 360.0 - 180.0
    return GimbalSample(pitch, yaw, heading, quat_from_euler(0.0, math.radians(pitch), math.radians(heading)))


class WorldEvent(enum.StrEnum):
    """A run event in ``world.mcap``'s ``/events`` and the view's log (the value is what the files hold)."""

    PAUSED = "paused"
    RESUMED = "resumed"
    CRASH = "crash"
    SIM = "sim"
    """A vehicle's simulated world changed (``SIM_*``): the wind, the pace."""
    CAPTURE = "capture"
    """A vehicle's camera took a picture (``capture_detail``)."""


def capture_detail(vehicle: int, c: Capture) -> dict[str, Any]:
    """A picture as ``/sim/events`` holds it: the geotag CAMERA_IMAGE_CAPTURED carries, from the ground truth."""
    return {
        "vehicle": vehicle,
        "index": c.index,
        "lat_deg": c.lat_deg,
        "lon_deg": c.lon_deg,
        "alt_amsl_m": c.alt_amsl_m,
        "relative_alt_m": c.relative_alt_m,
        "pos_ned_m": list(c.pos_ned_m),
        "q": list(c.q),
        "file_url": c.file_url,
    }
