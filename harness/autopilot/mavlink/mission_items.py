"""Mission items checked as each firmware checks them, one item at a time, as it arrives.

A mission upload refuses an item the firmware would refuse, with the ``MAV_MISSION_RESULT`` that firmware
answers, before anything reaches the flight core (which then checks the whole mission: the commands it
flies, finite coordinates, latitude and longitude in range):

- PX4 (``MavlinkMissionManager::parse_mavlink_mission_item``): an item with a position is in
  ``GLOBAL`` / ``GLOBAL_RELATIVE_ALT`` (or their ``_INT`` forms in a MISSION_ITEM_INT) and one of the
  commands that take a position; an item without one is in ``MISSION`` and one of the commands that take
  none. Any other frame (local frames, terrain frames, a frame of 200) is ``MAV_MISSION_UNSUPPORTED_FRAME``,
  any other command ``MAV_MISSION_UNSUPPORTED``; a region of interest with a mode it does not know is
  ``MAV_MISSION_INVALID_PARAM1``.
- ArduPilot (``AP_Mission::mavlink_int_to_mission_cmd``): a command it does not know is
  ``MAV_MISSION_UNSUPPORTED``; a command that stores a location must be in ``MISSION``, ``GLOBAL*``,
  ``GLOBAL_RELATIVE_ALT*`` or ``GLOBAL_TERRAIN_ALT*`` (else ``MAV_MISSION_UNSUPPORTED_FRAME``), with a
  latitude, longitude and altitude in range (``MAV_MISSION_INVALID_PARAM5_X`` / ``_PARAM6_Y`` / ``_PARAM7``).

    code, reason = px4_item_result(message)      # (MAV_MISSION_ACCEPTED, "") when PX4 takes it
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as _APM
from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.mavlink.messages import MAVLinkMessage

_M = mavlink2
ItemResult = tuple[int, str]
ACCEPTED: ItemResult = (_M.MAV_MISSION_ACCEPTED, "")

_PX4_GLOBAL_FRAMES = frozenset({_M.MAV_FRAME_GLOBAL, _M.MAV_FRAME_GLOBAL_RELATIVE_ALT})
_PX4_GLOBAL_INT_FRAMES = frozenset({_M.MAV_FRAME_GLOBAL_INT, _M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})
_ROI = frozenset({_M.MAV_CMD_NAV_ROI, _M.MAV_CMD_DO_SET_ROI})
_PX4_WITH_POSITION = frozenset(
    {
        _M.MAV_CMD_NAV_WAYPOINT,
        _M.MAV_CMD_NAV_LOITER_UNLIM,
        _M.MAV_CMD_NAV_LOITER_TIME,
        _M.MAV_CMD_NAV_LAND,
        _M.MAV_CMD_NAV_TAKEOFF,
        _M.MAV_CMD_NAV_LOITER_TO_ALT,
        _M.MAV_CMD_DO_SET_ROI_LOCATION,
        _M.MAV_CMD_NAV_VTOL_TAKEOFF,
        _M.MAV_CMD_NAV_VTOL_LAND,
        _M.MAV_CMD_CONDITION_GATE,
        _M.MAV_CMD_NAV_FENCE_RETURN_POINT,
        _M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
        _M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
        _M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
        _M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION,
        _M.MAV_CMD_NAV_RALLY_POINT,
        _M.MAV_CMD_COMPONENT_ARM_DISARM,
        _M.MAV_CMD_DO_AUTOTUNE_ENABLE,
    }
)
_PX4_WITHOUT_POSITION = frozenset(
    {
        _M.MAV_CMD_DO_JUMP,
        _M.MAV_CMD_DO_WINCH,
        _M.MAV_CMD_DO_GRIPPER,
        _M.MAV_CMD_DO_CHANGE_SPEED,
        _M.MAV_CMD_DO_SET_HOME,
        _M.MAV_CMD_DO_LAND_START,
        _M.MAV_CMD_DO_TRIGGER_CONTROL,
        _M.MAV_CMD_DO_DIGICAM_CONTROL,
        _M.MAV_CMD_DO_MOUNT_CONFIGURE,
        _M.MAV_CMD_DO_MOUNT_CONTROL,
        _M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
        _M.MAV_CMD_SET_CAMERA_FOCUS,
        _M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
        _M.MAV_CMD_IMAGE_START_CAPTURE,
        _M.MAV_CMD_IMAGE_STOP_CAPTURE,
        _M.MAV_CMD_VIDEO_START_CAPTURE,
        _M.MAV_CMD_VIDEO_STOP_CAPTURE,
        _M.MAV_CMD_DO_CONTROL_VIDEO,
        _M.MAV_CMD_DO_SET_CAM_TRIGG_DIST,
        _M.MAV_CMD_OBLIQUE_SURVEY,
        _M.MAV_CMD_DO_SET_CAM_TRIGG_INTERVAL,
        _M.MAV_CMD_SET_CAMERA_MODE,
        _M.MAV_CMD_SET_CAMERA_SOURCE,
        _M.MAV_CMD_DO_VTOL_TRANSITION,
        _M.MAV_CMD_NAV_DELAY,
        _M.MAV_CMD_NAV_RETURN_TO_LAUNCH,
        _M.MAV_CMD_DO_SET_ROI_WPNEXT_OFFSET,
        _M.MAV_CMD_DO_SET_ROI_NONE,
        _M.MAV_CMD_CONDITION_DELAY,
        _M.MAV_CMD_CONDITION_DISTANCE,
        _M.MAV_CMD_DO_SET_ACTUATOR,
        _M.MAV_CMD_DO_AUTOTUNE_ENABLE,
        _M.MAV_CMD_COMPONENT_ARM_DISARM,
    }
)


def _roi_mode(param1: float) -> int | None:
    return int(param1) if math.isfinite(param1) else None


def _is_int(m: MAVLinkMessage) -> bool:
    return bool(m.get_msgId() == _M.MAVLINK_MSG_ID_MISSION_ITEM_INT)


def px4_item_result(m: MAVLinkMessage) -> ItemResult:
    """What PX4 answers to one MISSION_ITEM(_INT): ``(MAV_MISSION_RESULT, reason)``."""
    frame, cmd = m.frame, m.command
    if frame in _PX4_GLOBAL_FRAMES or (_is_int(m) and frame in _PX4_GLOBAL_INT_FRAMES):
        if cmd in _ROI:
            if _roi_mode(m.param1) not in (_M.MAV_ROI_LOCATION, _M.MAV_ROI_NONE):
                return _M.MAV_MISSION_INVALID_PARAM1, f"item {m.seq}: region of interest mode {m.param1} refused"
            return ACCEPTED
        if cmd not in _PX4_WITH_POSITION:
            return _M.MAV_MISSION_UNSUPPORTED, f"item {m.seq}: command {cmd} unsupported in frame {frame}"
        return ACCEPTED
    if frame == _M.MAV_FRAME_MISSION:
        if cmd in _ROI:
            if _roi_mode(m.param1) not in (_M.MAV_ROI_NONE, _M.MAV_ROI_WPNEXT, _M.MAV_ROI_WPINDEX):
                return _M.MAV_MISSION_INVALID_PARAM1, f"item {m.seq}: region of interest mode {m.param1} refused"
            return ACCEPTED
        if cmd not in _PX4_WITHOUT_POSITION:
            return _M.MAV_MISSION_UNSUPPORTED, f"item {m.seq}: command {cmd} unsupported in frame {frame}"
        return ACCEPTED
    return _M.MAV_MISSION_UNSUPPORTED_FRAME, f"item {m.seq}: frame {frame} unsupported"


_AP_LOCATION = frozenset(
    {
        _M.MAV_CMD_NAV_WAYPOINT,
        _M.MAV_CMD_NAV_LOITER_UNLIM,
        _M.MAV_CMD_NAV_LOITER_TURNS,
        _M.MAV_CMD_NAV_LOITER_TIME,
        _M.MAV_CMD_NAV_RETURN_TO_LAUNCH,
        _M.MAV_CMD_NAV_LAND,
        _M.MAV_CMD_NAV_TAKEOFF,
        _M.MAV_CMD_NAV_CONTINUE_AND_CHANGE_ALT,
        _M.MAV_CMD_NAV_LOITER_TO_ALT,
        _M.MAV_CMD_NAV_SPLINE_WAYPOINT,
        _M.MAV_CMD_NAV_GUIDED_ENABLE,
        _M.MAV_CMD_NAV_VTOL_TAKEOFF,
        _M.MAV_CMD_NAV_VTOL_LAND,
        _M.MAV_CMD_NAV_PAYLOAD_PLACE,
        _M.MAV_CMD_DO_SET_HOME,
        _M.MAV_CMD_DO_LAND_START,
        _M.MAV_CMD_DO_SET_ROI,
        _M.MAV_CMD_DO_SET_ROI_LOCATION,
        _M.MAV_CMD_NAV_FENCE_RETURN_POINT,
        _M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
        _M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
        _M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
        _M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION,
        _M.MAV_CMD_NAV_RALLY_POINT,
    }
)
_AP_OTHER = frozenset(
    {
        _M.MAV_CMD_NAV_DELAY,
        _APM.MAV_CMD_NAV_ATTITUDE_TIME,
        _M.MAV_CMD_CONDITION_DELAY,
        _M.MAV_CMD_CONDITION_DISTANCE,
        _M.MAV_CMD_CONDITION_YAW,
        _M.MAV_CMD_DO_JUMP,
        _M.MAV_CMD_DO_CHANGE_SPEED,
        _M.MAV_CMD_DO_SET_RELAY,
        _M.MAV_CMD_DO_REPEAT_RELAY,
        _M.MAV_CMD_DO_SET_SERVO,
        _M.MAV_CMD_DO_REPEAT_SERVO,
        _M.MAV_CMD_DO_SET_ROI_NONE,
        _M.MAV_CMD_DO_DIGICAM_CONFIGURE,
        _M.MAV_CMD_DO_DIGICAM_CONTROL,
        _M.MAV_CMD_DO_MOUNT_CONTROL,
        _M.MAV_CMD_DO_SET_CAM_TRIGG_DIST,
        _M.MAV_CMD_DO_FENCE_ENABLE,
        _M.MAV_CMD_DO_PARACHUTE,
        _M.MAV_CMD_DO_INVERTED_FLIGHT,
        _M.MAV_CMD_DO_GRIPPER,
        _M.MAV_CMD_DO_AUTOTUNE_ENABLE,
        _APM.MAV_CMD_DO_SET_RESUME_REPEAT_DIST,
        _M.MAV_CMD_DO_GUIDED_LIMITS,
        _M.MAV_CMD_DO_ENGINE_CONTROL,
        _M.MAV_CMD_DO_VTOL_TRANSITION,
        _M.MAV_CMD_DO_WINCH,
        _APM.MAV_CMD_DO_SPRAYER,
        _APM.MAV_CMD_DO_AUX_FUNCTION,
        _M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
        _M.MAV_CMD_JUMP_TAG,
        _M.MAV_CMD_DO_JUMP_TAG,
        _M.MAV_CMD_IMAGE_START_CAPTURE,
        _M.MAV_CMD_IMAGE_STOP_CAPTURE,
        _M.MAV_CMD_SET_CAMERA_ZOOM,
        _M.MAV_CMD_SET_CAMERA_FOCUS,
        _M.MAV_CMD_VIDEO_START_CAPTURE,
        _M.MAV_CMD_VIDEO_STOP_CAPTURE,
        _M.MAV_CMD_STORAGE_FORMAT,
        _APM.MAV_CMD_NAV_SCRIPT_TIME,
    }
)
_AP_FRAMES = frozenset(
    {
        _M.MAV_FRAME_MISSION,
        _M.MAV_FRAME_GLOBAL,
        _M.MAV_FRAME_GLOBAL_INT,
        _M.MAV_FRAME_GLOBAL_RELATIVE_ALT,
        _M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        _M.MAV_FRAME_GLOBAL_TERRAIN_ALT,
        _M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
    }
)
_AP_ALT_MAX_M = 83_000.0
"""``LOCATION_ALT_MAX_M``: an altitude ArduPilot's location (centimetres in 24 bits) can hold."""


def ardupilot_item_result(m: MAVLinkMessage) -> ItemResult:
    """What ArduPilot answers to one MISSION_ITEM(_INT): ``(MAV_MISSION_RESULT, reason)``."""
    cmd, frame = m.command, m.frame
    if cmd not in _AP_LOCATION and cmd not in _AP_OTHER:
        return _M.MAV_MISSION_UNSUPPORTED, f"item {m.seq}: command {cmd} unsupported"
    if cmd not in _AP_LOCATION:
        return ACCEPTED
    if frame not in _AP_FRAMES:
        return _M.MAV_MISSION_UNSUPPORTED_FRAME, f"item {m.seq}: frame {frame} unsupported"
    lat, lon = (m.x * 1e-7, m.y * 1e-7) if _is_int(m) else (m.x, m.y)
    if not (math.isfinite(lat) and abs(lat) <= 90.0):
        return _M.MAV_MISSION_INVALID_PARAM5_X, f"item {m.seq}: latitude {lat} out of range"
    if not (math.isfinite(lon) and abs(lon) <= 180.0):
        return _M.MAV_MISSION_INVALID_PARAM6_Y, f"item {m.seq}: longitude {lon} out of range"
    if not (math.isfinite(m.z) and abs(m.z) < _AP_ALT_MAX_M):
        return _M.MAV_MISSION_INVALID_PARAM7, f"item {m.seq}: altitude {m.z} out of range"
    return ACCEPTED
