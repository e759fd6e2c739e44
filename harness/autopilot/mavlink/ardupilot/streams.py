"""ArduPilot's telemetry stream groups: REQUEST_DATA_STREAM and the ``SRx_*`` rates, and EKF_STATUS_REPORT.

ArduPilot streams messages in groups (``GCS_MAVLink`` ``ap_message`` lists) at the rate of the link's
``SRx_<group>`` parameter; REQUEST_DATA_STREAM(stream_id, rate, start) sets those parameters
(DroneKit asks for ALL at 4 Hz on connect, MAVProxy for each group). The server has one stream scheduler
for all its links, so a group goes out at the fastest rate any link asked for.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as apm
from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import VehicleState
from harness.autopilot.mavlink.messages import MAVLinkMessage

_M = mavlink2

GROUP_MESSAGES: dict[str, tuple[int, ...]] = {
    "RAW_SENS": (_M.MAVLINK_MSG_ID_HIGHRES_IMU,),
    "EXT_STAT": (_M.MAVLINK_MSG_ID_SYS_STATUS, _M.MAVLINK_MSG_ID_GPS_RAW_INT, _M.MAVLINK_MSG_ID_MISSION_CURRENT),
    "RC_CHAN": (),
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
"""What each group sends, among the messages this autopilot has builders for."""

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
