"""ArduPilot's telemetry stream groups: REQUEST_DATA_STREAM and the ``SRx_*`` rates, and EKF_STATUS_REPORT.

ArduPilot streams messages in groups (``GCS_MAVLink`` ``ap_message`` lists) at the rate of the link's
``SRx_<group>`` parameter; REQUEST_DATA_STREAM(stream_id, rate, start) sets those parameters
(DroneKit asks for ALL at 4 Hz on connect, MAVProxy for each group). The server has one stream scheduler
for all its links, so a group goes out at the fastest rate any link asked for.
"""

from __future__ import annotations

from collections.abc import Mapping

from pymavlink.dialects.v20 import ardupilotmega as apm
from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import VehicleState
from harness.autopilot.mavlink.ardupilot.rc import RADIO_CHANNELS, RcInput
from harness.autopilot.mavlink.messages import MAVLinkMessage, clamp_int, finite
from harness.autopilot.mavlink.telemetry import Builder

_M = mavlink2

GROUP_MESSAGES: dict[str, tuple[int, ...]] = {
    "RAW_SENS": (_M.MAVLINK_MSG_ID_RAW_IMU, _M.MAVLINK_MSG_ID_SCALED_IMU2, _M.MAVLINK_MSG_ID_SCALED_PRESSURE),
    "EXT_STAT": (
        _M.MAVLINK_MSG_ID_SYS_STATUS,
        _M.MAVLINK_MSG_ID_POWER_STATUS,
        apm.MAVLINK_MSG_ID_MEMINFO,
        _M.MAVLINK_MSG_ID_MISSION_CURRENT,
        _M.MAVLINK_MSG_ID_GPS_RAW_INT,
    ),
    "RC_CHAN": (_M.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW, _M.MAVLINK_MSG_ID_RC_CHANNELS, _M.MAVLINK_MSG_ID_RC_CHANNELS_RAW),
    "RAW_CTRL": (),
    "POSITION": (_M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, _M.MAVLINK_MSG_ID_LOCAL_POSITION_NED),
    "EXTRA1": (_M.MAVLINK_MSG_ID_ATTITUDE,),
    "EXTRA2": (_M.MAVLINK_MSG_ID_VFR_HUD,),
    "EXTRA3": (
        _M.MAVLINK_MSG_ID_SYSTEM_TIME,
        _M.MAVLINK_MSG_ID_BATTERY_STATUS,
        apm.MAVLINK_MSG_ID_EKF_STATUS_REPORT,
        _M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
    ),
    "PARAMS": (),
}
"""What each group sends (ArduCopter 4.x's ``STREAM_*_msgs`` lists, among the messages this autopilot has
builders for): RAW_SENS the IMUs and the barometer, EXT_STAT status, power and memory, RC_CHAN the radio and
the motor outputs."""

DATA_STREAM_GROUPS: dict[int, tuple[str, ...]] = {
    _M.MAV_DATA_STREAM_ALL: ("RAW_SENS", "EXT_STAT", "RC_CHAN", "RAW_CTRL", "POSITION", "EXTRA1", "EXTRA2", "EXTRA3"),
    _M.MAV_DATA_STREAM_RAW_SENSORS: ("RAW_SENS",),
    _M.MAV_DATA_STREAM_EXTENDED_STATUS: ("EXT_STAT",),
    _M.MAV_DATA_STREAM_RC_CHANNELS: ("RC_CHAN",),
    _M.MAV_DATA_STREAM_RAW_CONTROLLER: ("RAW_CTRL",),
    _M.MAV_DATA_STREAM_POSITION: ("POSITION",),
    _M.MAV_DATA_STREAM_EXTRA1: ("EXTRA1",),
    _M.MAV_DATA_STREAM_EXTRA2: ("EXTRA2",),
    _M.MAV_DATA_STREAM_EXTRA3: ("EXTRA3",),
}
"""REQUEST_DATA_STREAM stream_id -> the SRx groups it sets."""

MAX_RATE_HZ = 50.0

_EKF_GOOD_ATTITUDE = apm.EKF_ATTITUDE | apm.EKF_VELOCITY_HORIZ | apm.EKF_VELOCITY_VERT | apm.EKF_POS_VERT_ABS
_EKF_GOOD_LOCAL = apm.EKF_POS_HORIZ_REL | apm.EKF_PRED_POS_HORIZ_REL | apm.EKF_POS_VERT_AGL
_EKF_GOOD_GLOBAL = apm.EKF_POS_HORIZ_ABS | apm.EKF_PRED_POS_HORIZ_ABS


def ekf_flags(state: VehicleState) -> int:
    """EKF_STATUS_REPORT flags from the estimator's health (DroneKit's ``is_armable`` reads
    EKF_PRED_POS_HORIZ_ABS, its ``ekf_ok`` EKF_POS_HORIZ_ABS and EKF_CONST_POS_MODE)."""
    h = state.health
    flags = 0
    if h.gyro_ok and h.accel_ok:
        flags |= _EKF_GOOD_ATTITUDE
    if h.local_position_ok:
        flags |= _EKF_GOOD_LOCAL
    if h.gps_ok:
        flags |= _EKF_GOOD_GLOBAL
    else:
        flags |= apm.EKF_CONST_POS_MODE
    return flags


def ekf_status_report(_mav: mavlink2.MAVLink, s: VehicleState, _t: int) -> MAVLinkMessage:
    """EKF_STATUS_REPORT (ardupilotmega dialect; packed by the common-dialect codec like any message)."""
    good = s.health.gps_ok
    var = 0.05 if good else 1.0
    return apm.MAVLink_ekf_status_report_message(ekf_flags(s), var, var, var, 0.05, 0.0, 0.0)


_G = 9.80665
_MG_PER_M_S2 = 1000.0 / _G


def _i16(v: float) -> int:
    return clamp_int(finite(v), -32768, 32767)


def _imu_fields(s: VehicleState) -> list[int]:
    """Accelerations in mG, rates in mrad/s, field in mGauss (ArduPilot's RAW_IMU / SCALED_IMUn units)."""
    ax, ay, az = s.accel_body_m_s2
    p, q, r = s.rates_body_rad_s
    mx, my, mz = s.mag_body_gauss or (0.0, 0.0, 0.0)
    return [_i16(ax * _MG_PER_M_S2), _i16(ay * _MG_PER_M_S2), _i16(az * _MG_PER_M_S2)] + [
        _i16(v * 1000.0) for v in (p, q, r, mx, my, mz)
    ]


def raw_imu(mav: mavlink2.MAVLink, s: VehicleState, _t: int) -> MAVLinkMessage:
    return mav.raw_imu_encode(s.t_ns // 1000, *_imu_fields(s), 0, 4500)


def scaled_imu2(mav: mavlink2.MAVLink, s: VehicleState, t: int) -> MAVLinkMessage:
    """The second IMU (SITL has two; here both read the one simulated sensor)."""
    return mav.scaled_imu2_encode(t, *_imu_fields(s), 4500)


def scaled_pressure(mav: mavlink2.MAVLink, s: VehicleState, t: int) -> MAVLinkMessage:
    return mav.scaled_pressure_encode(t, (s.baro_pa or 0.0) / 100.0, 0.0, 2500, 0)


def power_status(mav: mavlink2.MAVLink, _s: VehicleState, _t: int) -> MAVLinkMessage:
    return mav.power_status_encode(5000, 0, 0)


def meminfo(_mav: mavlink2.MAVLink, _s: VehicleState, _t: int) -> MAVLinkMessage:
    return apm.MAVLink_meminfo_message(0, 65535, 131072)


def rc_builders(rc: RcInput) -> Mapping[int, Builder]:
    """RC_CHANNELS, RC_CHANNELS_RAW (the RC input: radio and overrides) and SERVO_OUTPUT_RAW (the motors in
    PWM, 1000-2000 us, ArduCopter's quad-X order, which is the core's)."""

    def rc_channels(mav: mavlink2.MAVLink, s: VehicleState, t: int) -> MAVLinkMessage:
        return mav.rc_channels_encode(t, RADIO_CHANNELS, *rc.channels(s.t_ns), 255)

    def rc_channels_raw(mav: mavlink2.MAVLink, s: VehicleState, t: int) -> MAVLinkMessage:
        return mav.rc_channels_raw_encode(t, 0, *rc.channels(s.t_ns)[:8], 255)

    def servo_output_raw(mav: mavlink2.MAVLink, s: VehicleState, _t: int) -> MAVLinkMessage:
        pwm = [clamp_int(1000.0 + 1000.0 * finite(m), 1000, 2000) if s.armed else 1000 for m in s.motors[:4]]
        pwm += [0] * (16 - len(pwm))
        return mav.servo_output_raw_encode((s.t_ns // 1000) & 0xFFFFFFFF, 0, *pwm)

    return {
        _M.MAVLINK_MSG_ID_RC_CHANNELS: rc_channels,
        _M.MAVLINK_MSG_ID_RC_CHANNELS_RAW: rc_channels_raw,
        _M.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW: servo_output_raw,
    }


SENSOR_BUILDERS: Mapping[int, Builder] = {
    _M.MAVLINK_MSG_ID_RAW_IMU: raw_imu,
    _M.MAVLINK_MSG_ID_SCALED_IMU2: scaled_imu2,
    _M.MAVLINK_MSG_ID_SCALED_PRESSURE: scaled_pressure,
    _M.MAVLINK_MSG_ID_POWER_STATUS: power_status,
    apm.MAVLINK_MSG_ID_MEMINFO: meminfo,
}
