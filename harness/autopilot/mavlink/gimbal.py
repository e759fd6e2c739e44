"""A gimbal as PX4 SITL with a gimbal model has one: gimbal protocol v2, the manager in the autopilot
(component 1) for a non-MAVLink gimbal device (``gimbal_device_id`` 1), which the manager speaks for.

- GIMBAL_MANAGER_INFORMATION and GIMBAL_DEVICE_INFORMATION on request (REQUEST_MESSAGE, what MAVSDK's
  gimbal discovery asks after the first heartbeat);
- GIMBAL_DEVICE_ATTITUDE_STATUS at 5 Hz (roll and pitch earth-stabilised, yaw in the vehicle frame,
  ``GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME``) and GIMBAL_MANAGER_STATUS at 1 Hz and after every change of
  control, from the first time a client shows it uses the gimbal (asks for either INFORMATION message, sends a
  gimbal message or command): PX4 streams them always, but a MAVSDK that never touches its gimbal plugin
  never asks, and the vehicles of a swarm that nobody points a camera on are spared 6 messages a second each
  (SET_MESSAGE_INTERVAL starts or changes them at any time); both are in the vehicle's tlog like everything sent;
- control: MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE (1001: param1/2 primary sysid/compid, 3/4 secondary; -1 =
  the sender takes it, -2 = leave, -3 = release); setpoints from anyone are obeyed while nobody holds
  control, otherwise from the primary (or secondary) controller only (PX4 ignores others);
- setpoints: GIMBAL_MANAGER_SET_ATTITUDE (quaternion, or NaN quaternion and angular rates),
  GIMBAL_MANAGER_SET_PITCHYAW, MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW (1000: pitch/yaw deg, or NaN and rates
  in deg/s; flags param5 / COMMAND_INT x), MAV_CMD_DO_SET_ROI_LOCATION (195: point at a global position,
  tracked as the vehicle moves), MAV_CMD_DO_SET_ROI_NONE (197).

The device itself is the autopilot's ``gimbal`` service (``harness.autopilot.gimbal``): it moves in lockstep
on sim time, at most 90 deg/s per axis towards its target (or at the commanded rates), within pitch [-90, +30]
deg and yaw [-180, +180] deg around the vehicle's heading; with the yaw lock flag the yaw target is held in the
earth frame as the vehicle turns. Its attitude also goes to the recordings with each tick (END-TICK-AC).
Nothing of the gimbal touches the flight.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import CommandResult, VehicleState
from harness.autopilot.gimbal import PITCH_MAX, PITCH_MIN, YAW_MAX, YAW_MIN, clamp, wrap180
from harness.autopilot.mavlink.commands import CommandIn, CommandOutcome
from harness.autopilot.mavlink.messages import MAVLinkMessage, Origin, Out
from harness.autopilot.mavlink.service import CommandHandler, Service, outcome
from harness.autopilot.mavlink.telemetry import Builder
from harness.autopilot.services import Gimbal, System

_M = mavlink2
DEVICE_ID = 1
CMD_PITCHYAW = 1000
CMD_CONFIGURE = 1001
CMD_ROI_LOCATION = 195
CMD_ROI_NONE = 197
ATTITUDE_PERIOD_NS = 200_000_000
STATUS_PERIOD_NS = 1_000_000_000
_CAPS = (
    _M.GIMBAL_MANAGER_CAP_FLAGS_HAS_NEUTRAL
    | _M.GIMBAL_MANAGER_CAP_FLAGS_HAS_ROLL_LOCK
    | _M.GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_AXIS
    | _M.GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_LOCK
    | _M.GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_AXIS
    | _M.GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_FOLLOW
    | _M.GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_LOCK
    | _M.GIMBAL_MANAGER_CAP_FLAGS_CAN_POINT_LOCATION_GLOBAL
)


def euler_of(q: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in degrees of a quaternion (w, x, y, z), aerospace ZYX."""
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(clamp(2 * (w * y - z * x), -1.0, 1.0))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return math.degrees(roll), math.degrees(pitch), math.degrees(yaw)


def quat_of(roll_deg: float, pitch_deg: float, yaw_deg: float) -> tuple[float, float, float, float]:
    r, p, y = (math.radians(a) / 2 for a in (roll_deg, pitch_deg, yaw_deg))
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


class GimbalService(Service):
    message_ids = frozenset(
        {_M.MAVLINK_MSG_ID_GIMBAL_MANAGER_SET_ATTITUDE, _M.MAVLINK_MSG_ID_GIMBAL_MANAGER_SET_PITCHYAW}
    )
    STREAMS: Mapping[int, int] = {
        _M.MAVLINK_MSG_ID_GIMBAL_DEVICE_ATTITUDE_STATUS: ATTITUDE_PERIOD_NS,
        _M.MAVLINK_MSG_ID_GIMBAL_MANAGER_STATUS: STATUS_PERIOD_NS,
    }
    """Started when a client first uses the gimbal (see the module's docstring)."""

    def __init__(self, api: System, gimbal: Gimbal, sysid: int) -> None:
        super().__init__()
        self.api = api
        self.gimbal = gimbal
        self.sysid = sysid
        self.primary = (0, 0)
        self.secondary = (0, 0)
        self.sender = (0, 0)
        """(sysid, compid) of the command being executed."""
        self._set_interval: Callable[[int, float], bool] | None = None
        self.streaming = False
        self.builders: Mapping[int, Builder] = {
            _M.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION: self._manager_information,
            _M.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION: self._device_information,
            _M.MAVLINK_MSG_ID_GIMBAL_MANAGER_STATUS: self._manager_status,
            _M.MAVLINK_MSG_ID_GIMBAL_DEVICE_ATTITUDE_STATUS: self._attitude_status,
        }

    def bind_streams(self, set_interval: Callable[[int, float], bool]) -> None:
        """The server's SET_MESSAGE_INTERVAL (``StreamScheduler.set_interval``: message id, interval in µs)."""
        self._set_interval = set_interval

    def in_use(self) -> None:
        """A client uses the gimbal: stream its attitude and the manager's status from now on."""
        if self.streaming or self._set_interval is None:
            return
        self.streaming = True
        for msg_id, period_ns in self.STREAMS.items():
            self._set_interval(msg_id, period_ns / 1000)

    # ------------------------------------------------------------------ messages
    def _manager_information(self, mav: mavlink2.MAVLink, s: VehicleState, t_ms: int) -> MAVLinkMessage:
        self.in_use()
        r = math.radians
        return mav.gimbal_manager_information_encode(
            t_ms, _CAPS, DEVICE_ID, 0.0, 0.0, r(PITCH_MIN), r(PITCH_MAX), r(YAW_MIN), r(YAW_MAX)
        )

    def _device_information(self, mav: mavlink2.MAVLink, s: VehicleState, t_ms: int) -> MAVLinkMessage:
        self.in_use()
        r = math.radians
        caps = (
            _M.GIMBAL_DEVICE_CAP_FLAGS_HAS_NEUTRAL
            | _M.GIMBAL_DEVICE_CAP_FLAGS_HAS_ROLL_LOCK
            | _M.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_AXIS
            | _M.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_LOCK
            | _M.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_AXIS
            | _M.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_FOLLOW
            | _M.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_LOCK
        )
        return mav.gimbal_device_information_encode(
            t_ms, b"uav-harness", b"sim 2-axis gimbal", b"", 1, 1, 0, caps, 0,
            0.0, 0.0, r(PITCH_MIN), r(PITCH_MAX), r(YAW_MIN), r(YAW_MAX), DEVICE_ID,
        )  # fmt: skip

    def _manager_status(self, mav: mavlink2.MAVLink, s: VehicleState, t_ms: int) -> MAVLinkMessage:
        flags = _M.GIMBAL_MANAGER_FLAGS_ROLL_LOCK | _M.GIMBAL_MANAGER_FLAGS_PITCH_LOCK
        if self.gimbal.attitude().yaw_lock:
            flags |= _M.GIMBAL_MANAGER_FLAGS_YAW_LOCK
        return mav.gimbal_manager_status_encode(t_ms, flags, DEVICE_ID, *self.primary, *self.secondary)

    def _attitude_status(self, mav: mavlink2.MAVLink, s: VehicleState, t_ms: int) -> MAVLinkMessage:
        g = self.gimbal.attitude()
        flags = (
            _M.GIMBAL_DEVICE_FLAGS_ROLL_LOCK
            | _M.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
            | _M.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
        )
        if g.yaw_lock:
            flags |= _M.GIMBAL_DEVICE_FLAGS_YAW_LOCK
        q = quat_of(0.0, g.pitch_deg, g.yaw_deg)
        r = math.radians
        return mav.gimbal_device_attitude_status_encode(
            0, 0, t_ms, flags, q, 0.0, r(g.pitch_rate_deg_s), r(g.yaw_rate_deg_s), 0,
            wrap180(math.degrees(s.yaw_rad) + g.yaw_deg) * math.pi / 180.0, float("nan"), DEVICE_ID,
        )  # fmt: skip

    def attitude_deg(self) -> tuple[float, float]:
        """(pitch, yaw relative to the vehicle) of the device now, degrees."""
        g = self.gimbal.attitude()
        return g.pitch_deg, g.yaw_deg

    # ------------------------------------------------------------------ control
    def _may_control(self, sysid: int, compid: int) -> bool:
        return self.primary == (0, 0) or (sysid, compid) in (self.primary, self.secondary)

    def _setpoint(self, pitch: float, yaw: float, pitch_rate: float, yaw_rate: float, flags: int) -> str:
        """Angles in degrees (NaN = use the rates, deg/s); a reason when refused."""
        yaw_lock = bool(flags & _M.GIMBAL_MANAGER_FLAGS_YAW_LOCK)
        if not (math.isnan(pitch) or math.isnan(yaw)):
            result = self.gimbal.set_angles(pitch, yaw, yaw_lock)
        else:
            pr = 0.0 if math.isnan(pitch_rate) else pitch_rate
            yr = 0.0 if math.isnan(yaw_rate) else yaw_rate
            result = self.gimbal.set_rates(pr, yr, yaw_lock)
        return result.reason

    def handle(self, m: MAVLinkMessage, origin: Origin, now: int) -> list[Out]:
        self.in_use()
        if m.gimbal_device_id not in (0, DEVICE_ID) or not self._may_control(origin.sysid, origin.compid):
            return []
        if m.get_msgId() == _M.MAVLINK_MSG_ID_GIMBAL_MANAGER_SET_ATTITUDE:
            q = tuple(m.q)
            d = math.degrees
            if all(math.isfinite(v) for v in q):
                _roll, pitch, yaw = euler_of(q)
                self._setpoint(pitch, yaw, math.nan, math.nan, m.flags)
            else:
                self._setpoint(math.nan, math.nan, d(m.angular_velocity_y), d(m.angular_velocity_z), m.flags)
        else:  # GIMBAL_MANAGER_SET_PITCHYAW: radians
            d = math.degrees
            self._setpoint(d(m.pitch), d(m.yaw), d(m.pitch_rate), d(m.yaw_rate), m.flags)
        return []

    def commands(self) -> Mapping[int, CommandHandler]:
        return {
            CMD_PITCHYAW: self._cmd_pitchyaw,
            CMD_CONFIGURE: self._cmd_configure,
            CMD_ROI_LOCATION: self._cmd_roi,
            CMD_ROI_NONE: self._cmd_roi_none,
        }

    def _cmd_pitchyaw(self, c: CommandIn) -> CommandOutcome:
        self.in_use()
        p = c.params
        flags = int(p[4]) if math.isfinite(p[4]) else 0
        device = p[6]
        if math.isfinite(device) and int(device) not in (0, DEVICE_ID):
            return outcome(CommandResult.denied(f"gimbal: no gimbal device {int(device)}"))
        reason = self._setpoint(p[0], p[1], p[2], p[3], flags)
        return outcome(CommandResult.denied(reason) if reason else CommandResult.accepted())

    def _cmd_configure(self, c: CommandIn) -> CommandOutcome:
        """Who controls the gimbal: -1 = the sender (``sender``, set by the registry from the command's
        origin), -2 = leave as is, -3 = release."""
        self.in_use()
        sysid, compid = self.sender
        p = [v if math.isfinite(v) else -2.0 for v in c.params[:4]]

        def pick(sys_v: float, comp_v: float, current: tuple[int, int]) -> tuple[int, int]:
            if sys_v == -1 or comp_v == -1:
                return (sysid, compid)
            if sys_v == -3 or comp_v == -3:
                return (0, 0)
            if sys_v == -2 or comp_v == -2:
                return current
            return (int(clamp(sys_v, 0, 255)), int(clamp(comp_v, 0, 255)))

        self.primary = pick(p[0], p[1], self.primary)
        self.secondary = pick(p[2], p[3], self.secondary)
        assert self.mav is not None
        status = self._manager_status(self.mav, self.api.telemetry.state(), self._t_ms())
        return outcome(CommandResult.accepted(), [status])

    def _t_ms(self) -> int:
        return (max(self.api.telemetry.state().t_ns, 0) // 1_000_000) & 0xFFFFFFFF

    def _cmd_roi(self, c: CommandIn) -> CommandOutcome:
        self.in_use()
        p = c.params
        if c.frame is not None:
            lat, lon = p[4] / 1e7, p[5] / 1e7
        else:
            lat, lon = p[4], p[5]
        return outcome(self.gimbal.point_at(lat, lon, p[6]))

    def _cmd_roi_none(self, c: CommandIn) -> CommandOutcome:
        reason = self._setpoint(0.0, 0.0, math.nan, math.nan, 0)
        return outcome(CommandResult.denied(reason) if reason else CommandResult.accepted())
