"""The vehicle's camera as PX4 SITL's simulated MAVLink camera presents it: a component of its own
(``MAV_COMP_ID_CAMERA``, 100, HEARTBEAT type ``MAV_TYPE_CAMERA``) of the vehicle's system, speaking the MAVLink
camera protocol v2 for the autopilot's ``camera`` device (``harness.autopilot.camera``).

Its HEARTBEAT goes out from the first time a client looks for cameras (asks the autopilot for CAMERA_INFORMATION,
as MAVSDK's camera plugin and ground stations do, or addresses the camera): *unlike* a PX4 SITL model with a
camera, which always sends it. pymavlink keeps one HEARTBEAT per system, so a script that never looks for a camera
would otherwise read the camera's (``set_mode`` takes its autopilot type for the vehicle's).

- On request (MAV_CMD_REQUEST_MESSAGE, or the older REQUEST_CAMERA_INFORMATION 521 / _SETTINGS 522 /
  STORAGE_INFORMATION 525 / CAMERA_CAPTURE_STATUS 527): CAMERA_INFORMATION (photo and video capture, modes,
  survey mode; no definition file, no video stream), CAMERA_SETTINGS (the mode), STORAGE_INFORMATION (one
  simulated card), CAMERA_CAPTURE_STATUS (image count, interval, video time), CAMERA_IMAGE_CAPTURED of any index
  taken (param2: the index; MAVSDK's photo list asks for each).
- Commands: SET_CAMERA_MODE (530), IMAGE_START_CAPTURE (2000: param2 interval, param3 count, 1 = one picture),
  IMAGE_STOP_CAPTURE (2001), VIDEO_START_CAPTURE / STOP (2500 / 2501), STORAGE_FORMAT (526),
  RESET_CAMERA_SETTINGS (529), each answered by COMMAND_ACK from the camera component.
- To the autopilot (component 1): DO_SET_CAM_TRIGG_DIST (206) and DO_SET_CAM_TRIGG_INTERVAL (214), in missions
  too (the mission re-issues its camera items as PX4 does).
- Each picture: CAMERA_IMAGE_CAPTURED to everyone from the camera (the geotag from the ground truth at the tick it
  was taken, ``capture_result`` 1, a ``file_url``), and CAMERA_TRIGGER from the autopilot (PX4's trigger feedback).

Nothing of this runs while nobody uses the camera: the per-tick work is one test for new pictures.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import CommandResult, VehicleState
from harness.autopilot.camera import MODE_IMAGE, MODE_VIDEO, CameraDevice, Capture
from harness.autopilot.mavlink.commands import CommandIn, CommandOutcome
from harness.autopilot.mavlink.messages import MAVLinkMessage, Origin, Out
from harness.autopilot.mavlink.service import CommandHandler, Service, outcome

_M = mavlink2
COMPID = _M.MAV_COMP_ID_CAMERA
CMD_TRIGG_INTERVAL = 214
_COMMANDS = (_M.MAVLINK_MSG_ID_COMMAND_LONG, _M.MAVLINK_MSG_ID_COMMAND_INT)
_FLAGS = (
    _M.CAMERA_CAP_FLAGS_CAPTURE_VIDEO
    | _M.CAMERA_CAP_FLAGS_CAPTURE_IMAGE
    | _M.CAMERA_CAP_FLAGS_HAS_MODES
    | _M.CAMERA_CAP_FLAGS_CAN_CAPTURE_IMAGE_IN_VIDEO_MODE
    | _M.CAMERA_CAP_FLAGS_HAS_IMAGE_SURVEY_MODE
)
CARD_MIB = 64_000.0
IMAGE_MIB = 4.0


def _t_ms(state: VehicleState) -> int:
    return (max(state.t_ns, 0) // 1_000_000) & 0xFFFFFFFF


class CameraComponent(Service):
    """Component 100 of the vehicle's system. ``handle_component`` takes what is addressed to it; ``commands``
    are the autopilot's own camera commands; ``tick`` sends the new pictures."""

    compid = COMPID

    def __init__(self, camera: CameraDevice, state: Callable[[], VehicleState]) -> None:
        super().__init__()
        self.camera = camera
        self.state = state
        self.cam_mav: mavlink2.MAVLink | None = None
        """The camera component's encoder (messages built with it are framed by the server as component 100)."""
        self.announced = False
        """Whether the component sends its HEARTBEAT: from the first time a client looks for cameras."""

    def looked_for(self, m: MAVLinkMessage) -> None:
        """A command to the autopilot: asking it for CAMERA_INFORMATION is how a client looks for cameras (MAVSDK's
        camera plugin asks every component that heartbeats, the autopilot first): the camera answers from then on."""
        cmd = m.command
        if cmd == _M.MAV_CMD_REQUEST_CAMERA_INFORMATION or (
            cmd == _M.MAV_CMD_REQUEST_MESSAGE and m.param1 == _M.MAVLINK_MSG_ID_CAMERA_INFORMATION
        ):
            self.announced = True

    def bind_component(self, mav: mavlink2.MAVLink) -> None:
        self.cam_mav = mav

    # ------------------------------------------------------------------ identity
    def heartbeat(self) -> MAVLinkMessage | None:
        if not self.announced:
            return None
        assert self.cam_mav is not None
        return self.cam_mav.heartbeat_encode(_M.MAV_TYPE_CAMERA, _M.MAV_AUTOPILOT_INVALID, 0, 0, _M.MAV_STATE_ACTIVE, 3)

    # ------------------------------------------------------------------ messages (camera component)
    def _message(self, msg_id: int, index: float) -> MAVLinkMessage | None:
        mav = self.cam_mav
        assert mav is not None
        s = self.state()
        t = _t_ms(s)
        st = self.camera.state()
        if msg_id == _M.MAVLINK_MSG_ID_CAMERA_INFORMATION:
            return mav.camera_information_encode(
                t, list(b"uav-harness".ljust(32, b"\0")), list(b"sim survey camera".ljust(32, b"\0")),
                1, 8.8, 13.2, 8.8, 5472, 3648, 0, _FLAGS, 0, b"",
            )  # fmt: skip
        if msg_id == _M.MAVLINK_MSG_ID_CAMERA_SETTINGS:
            return mav.camera_settings_encode(t, st.mode, math.nan, math.nan)
        if msg_id == _M.MAVLINK_MSG_ID_STORAGE_INFORMATION:
            used = IMAGE_MIB * len(st.captures)
            return mav.storage_information_encode(
                t, 1, 1, _M.STORAGE_STATUS_READY, CARD_MIB, used, CARD_MIB - used, 90.0, 90.0,
                _M.STORAGE_TYPE_SD, b"sim card", _M.STORAGE_USAGE_FLAG_SET | _M.STORAGE_USAGE_FLAG_PHOTO,
            )  # fmt: skip
        if msg_id == _M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS:
            return self._capture_status(t)
        if msg_id == _M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED:
            caps = self.camera.captures()
            i = int(index) if math.isfinite(index) else -1
            if not caps:
                return None
            return self._captured(caps[i] if 0 <= i < len(caps) else caps[-1])
        return None

    def _capture_status(self, t_ms: int) -> MAVLinkMessage:
        assert self.cam_mav is not None
        st = self.camera.state()
        image = 3 if st.interval_ns else 0  # 3: interval capture in progress
        video = 1 if st.video_since_ns is not None else 0
        rec_ms = 0
        if st.video_since_ns is not None:
            rec_ms = max(0, (self.state().t_ns - st.video_since_ns) // 1_000_000)
        used = IMAGE_MIB * len(st.captures)
        return self.cam_mav.camera_capture_status_encode(
            t_ms, image, video, st.interval_ns / 1e9, rec_ms, CARD_MIB - used, len(st.captures)
        )

    def _captured(self, c: Capture) -> MAVLinkMessage:
        assert self.cam_mav is not None
        t_ms = (c.t_ns // 1_000_000) & 0xFFFFFFFF
        return self.cam_mav.camera_image_captured_encode(
            t_ms, 0, 0, round(c.lat_deg * 1e7), round(c.lon_deg * 1e7), round(c.alt_amsl_m * 1000),
            round(c.relative_alt_m * 1000), list(c.q), c.index, 1, c.file_url.encode(),
        )  # fmt: skip

    def handle_component(self, m: MAVLinkMessage, origin: Origin) -> list[Out]:
        """A message addressed to component 100: commands are executed and ACKed from it; the rest ignored."""
        if m.get_msgId() not in _COMMANDS:
            return []
        assert self.cam_mav is not None
        self.announced = True
        c = CommandIn.from_message(m)
        result, followups = self._command(c)
        ack = self.cam_mav.command_ack_encode(c.command, int(result.result), 0, 0, origin.sysid, origin.compid)
        return [Out(ack, origin, compid=COMPID), *(Out(f, origin, compid=COMPID) for f in followups)]

    def _command(self, c: CommandIn) -> tuple[CommandResult, list[MAVLinkMessage]]:
        p = c.params
        cmd = c.command
        cam = self.camera
        if cmd == _M.MAV_CMD_REQUEST_MESSAGE:
            msg = self._message(int(p[0]), p[1])
            if msg is None:
                return CommandResult.denied(f"camera: no message {int(p[0])}"), []
            return CommandResult.accepted(), [msg]
        legacy = {
            _M.MAV_CMD_REQUEST_CAMERA_INFORMATION: _M.MAVLINK_MSG_ID_CAMERA_INFORMATION,
            _M.MAV_CMD_REQUEST_CAMERA_SETTINGS: _M.MAVLINK_MSG_ID_CAMERA_SETTINGS,
            _M.MAV_CMD_REQUEST_STORAGE_INFORMATION: _M.MAVLINK_MSG_ID_STORAGE_INFORMATION,
            _M.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS: _M.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS,
        }
        if cmd in legacy:
            msg = self._message(legacy[cmd], math.nan)
            return CommandResult.accepted(), [] if msg is None else [msg]
        if cmd == _M.MAV_CMD_SET_CAMERA_MODE:
            mode = int(p[1]) if math.isfinite(p[1]) else -1
            return cam.set_mode(MODE_VIDEO if mode == _M.CAMERA_MODE_VIDEO else mode), []
        if cmd == _M.MAV_CMD_IMAGE_START_CAPTURE:
            total = int(p[2]) if math.isfinite(p[2]) else 1
            return cam.start_capture(p[1] if math.isfinite(p[1]) else 0.0, total), []
        if cmd == _M.MAV_CMD_IMAGE_STOP_CAPTURE:
            return cam.stop_capture(), []
        if cmd in (_M.MAV_CMD_VIDEO_START_CAPTURE, _M.MAV_CMD_VIDEO_STOP_CAPTURE):
            return cam.video(cmd == _M.MAV_CMD_VIDEO_START_CAPTURE, self.state().t_ns), []
        if cmd == _M.MAV_CMD_STORAGE_FORMAT:
            return cam.format_storage(), []
        if cmd == _M.MAV_CMD_RESET_CAMERA_SETTINGS:
            return cam.set_mode(MODE_IMAGE), []
        return CommandResult.unsupported(f"camera: command {cmd} not supported"), []

    # ------------------------------------------------------------------ the autopilot's camera commands
    def commands(self) -> Mapping[int, CommandHandler]:
        return {_M.MAV_CMD_DO_SET_CAM_TRIGG_DIST: self._trigg_dist, CMD_TRIGG_INTERVAL: self._trigg_interval}

    def _trigg_dist(self, c: CommandIn) -> CommandOutcome:
        p = c.params
        return outcome(self.camera.set_trigger_distance(p[0], p[2] == 1.0))

    def _trigg_interval(self, c: CommandIn) -> CommandOutcome:
        """DO_SET_CAM_TRIGG_INTERVAL: param1 the cycle in ms (0 stops)."""
        ms = c.params[0]
        if not math.isfinite(ms) or ms < 0:
            return outcome(CommandResult.denied("camera: bad trigger interval"))
        if ms == 0:
            return outcome(self.camera.stop_capture())
        return outcome(self.camera.start_capture(ms / 1000.0, 0))

    # ------------------------------------------------------------------ the pictures taken
    def tick(self, state: VehicleState, now: int) -> list[Out]:
        if not self.camera.new:
            return []
        assert self.mav is not None
        outs = []
        for c in self.camera.take_new():
            outs.append(Out(self._captured(c), compid=COMPID))
            outs.append(Out(self.mav.camera_trigger_encode(c.t_ns // 1000, c.index)))
        outs.append(Out(self._capture_status(_t_ms(state)), compid=COMPID))
        return outs
