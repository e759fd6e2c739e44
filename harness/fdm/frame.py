"""The sensor frame: what physics hands a vehicle's autopilot in every BEGIN-TICK-AC.

This is the contract between ``harness.fdm`` (which fills it) and ``harness.autopilot`` (which reads
it); the channel carries it as opaque bytes. Units are in the field names. Frames: body axes are FRD
(forward, right, down); the world frame is NED with its origin at the scenario's world origin.

A sensor that produced no new sample since the previous frame leaves its field ``None`` (GPS at 5-10 Hz,
baro and mag slower than the tick). ``truth`` is always present (ground truth, for recording, for the
network position and for the autopilot's ground-truth debug setting) but an autopilot in its normal
setting must not read it.
"""

from __future__ import annotations

import msgspec

from harness.core.geo import Quat, Vec3


class Imu(msgspec.Struct, array_like=True, frozen=True):
    accel_body_m_s2: Vec3
    """Specific force in body FRD (at rest, level: (0, 0, -9.81))."""
    gyro_body_rad_s: Vec3
    temperature_c: float = 25.0


class Mag(msgspec.Struct, array_like=True, frozen=True):
    field_body_gauss: Vec3


class Baro(msgspec.Struct, array_like=True, frozen=True):
    pressure_pa: float
    temperature_c: float
    alt_amsl_m: float
    """Pressure altitude from the standard atmosphere, as a real baro driver reports it."""


class Gps(msgspec.Struct, array_like=True, frozen=True):
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    vel_ned_m_s: Vec3
    fix_type: int
    """MAVLink GPS_FIX_TYPE: 0 no GPS, 1 no fix, 2 2D, 3 3D."""
    eph_m: float
    epv_m: float
    satellites: int
    measured_at_ns: int
    """Sim time at which this (latency-delayed) sample was taken."""


class Truth(msgspec.Struct, array_like=True, frozen=True):
    pos_ned_m: Vec3
    vel_ned_m_s: Vec3
    quat: Quat
    rates_body_rad_s: Vec3
    accel_ned_m_s2: Vec3
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    on_ground: bool
    crashed: bool


class SensorFrame(msgspec.Struct, array_like=True, frozen=True):
    t_ns: int
    vehicle: int
    imu: Imu
    truth: Truth
    mag: Mag | None = None
    baro: Baro | None = None
    gps: Gps | None = None


_enc = msgspec.msgpack.Encoder()
_dec = msgspec.msgpack.Decoder(SensorFrame)


def encode_frame(frame: SensorFrame) -> bytes:
    return _enc.encode(frame)


def decode_frame(data: bytes | memoryview) -> SensorFrame:
    """Decode a frame; raises ``msgspec.DecodeError``/``ValidationError`` when malformed."""
    return _dec.decode(data)


MOTOR_COUNT = 4
"""Quad-X. Motor order and spin follow PX4's quad-X: 1 front-right CCW, 2 rear-left CCW,
3 front-left CW, 4 rear-right CW (index 0..3). Commands are normalised throttle in [0, 1]."""
