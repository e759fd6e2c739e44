"""COMMAND_LONG / COMMAND_INT (and the SET_MODE message): validate, execute through the autopilot API,
answer with a COMMAND_ACK at once.

Every command gets an ACK: UNSUPPORTED for unknown ones (never silence), DENIED or TEMPORARILY_REJECTED
with a reason (the server sends it as STATUSTEXT) for unsafe or invalid ones. A NaN means "unset / use
the default" where MAVLink says so (takeoff altitude, reposition coordinates, yaw); elsewhere NaN and
infinities are refused. A retransmission (COMMAND_LONG with ``confirmation`` > 0, or the same COMMAND_INT
again within a second) is answered with the first ACK and not executed twice.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import CommandResult, FlightMode, GeoPoint, MavCmd, MavFrame, Result
from harness.autopilot.mavlink.messages import INT32_MAX, MAVLinkMessage, is_set
from harness.autopilot.services import System

RequestMessage = Callable[[int], "MAVLinkMessage | str | None"]
"""msg id -> the message, None when unknown, or a str reason when known but not available now."""

CMD_SET_MESSAGE_INTERVAL = 511
CMD_REQUEST_MESSAGE = 512
CMD_REQUEST_AUTOPILOT_CAPABILITIES = 520
CMD_GET_HOME_POSITION = 410
CMD_INJECT_FAILURE = 420
CMD_DO_SET_MISSION_CURRENT = 224
FORCE_MAGIC = 21196
RETRANSMIT_WINDOW_NS = 3_000_000_000
_AUTOPILOT_VERSION_ID = mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION
_GLOBAL_FRAMES = (MavFrame.GLOBAL, MavFrame.GLOBAL_RELATIVE_ALT, MavFrame.GLOBAL_INT, MavFrame.GLOBAL_RELATIVE_ALT_INT)
"""COMMAND_INT frames for a global position; the _INT and plain names mean the same here (MAVSDK's
do_orbit sends GLOBAL_RELATIVE_ALT)."""
_INT_UNSET = (INT32_MAX, -INT32_MAX - 1)
"""COMMAND_INT x/y meaning 'unset': INT32_MAX (MAVLink), and INT32_MIN, which is what MAVSDK's
``int32_t(round(NAN * 1e7))`` yields on x86 (its do_orbit with NaN centre)."""


@dataclass(frozen=True, slots=True)
class CommandIn:
    """COMMAND_LONG and COMMAND_INT in one shape. For COMMAND_INT, ``params[4:6]`` are the raw x/y ints."""

    command: int
    params: tuple[float, float, float, float, float, float, float]
    frame: int | None = None
    """None for COMMAND_LONG."""
    confirmation: int = 0

    @classmethod
    def from_message(cls, m: MAVLinkMessage) -> CommandIn:
        if m.get_msgId() == mavlink2.MAVLINK_MSG_ID_COMMAND_INT:
            p = (m.param1, m.param2, m.param3, m.param4, float(m.x), float(m.y), m.z)
            return cls(m.command, p, m.frame, 0)
        p = (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)
        return cls(m.command, p, None, m.confirmation)

    @property
    def key(self) -> tuple[object, ...]:
        return (self.command, self.frame, tuple(repr(v) for v in self.params))


@dataclass(slots=True)
class CommandOutcome:
    result: CommandResult
    followups: list[MAVLinkMessage] = field(default_factory=list)
    """Sent after the ACK to the sender (a requested message)."""
    mode_or_arming_changed: bool = False
    replayed: bool = False
    notice: str = ""
    """Said as a CRITICAL STATUSTEXT after the ACK of an accepted command (what the vehicle changed in it)."""


class CommandService:
    """Executes commands against one autopilot. Called from the server thread only."""

    def __init__(
        self,
        api: System,
        request_message: RequestMessage,
        set_interval: Callable[[int, float], bool],
    ) -> None:
        self.api = api
        self.request_message = request_message
        self.set_interval = set_interval
        self._last: dict[tuple[object, ...], tuple[tuple[object, ...], int, CommandOutcome]] = {}
        self._handlers: dict[int, Callable[[CommandIn], CommandOutcome]] = {
            MavCmd.ARM_DISARM: self._arm,
            MavCmd.NAV_TAKEOFF: self._takeoff,
            MavCmd.NAV_LAND: lambda c: self._mode_cmd(self.api.action.land()),
            MavCmd.NAV_RETURN_TO_LAUNCH: lambda c: self._mode_cmd(self.api.action.return_to_launch()),
            MavCmd.DO_SET_MODE: self._do_set_mode,
            MavCmd.DO_REPOSITION: self._reposition,
            MavCmd.MISSION_START: self._mission_start,
            MavCmd.DO_CHANGE_SPEED: self._change_speed,
            MavCmd.DO_ORBIT: self._orbit,
            MavCmd.DO_SET_HOME: self._set_home,
            CMD_INJECT_FAILURE: self._inject_failure,
            MavCmd.DO_GRIPPER: self._gripper,
            CMD_DO_SET_MISSION_CURRENT: self._set_mission_current,
            CMD_SET_MESSAGE_INTERVAL: self._set_message_interval,
            CMD_REQUEST_MESSAGE: self._request_message,
            CMD_REQUEST_AUTOPILOT_CAPABILITIES: lambda c: self._send_message(_AUTOPILOT_VERSION_ID),
            CMD_GET_HOME_POSITION: lambda c: self._send_message(mavlink2.MAVLINK_MSG_ID_HOME_POSITION),
        }

    def override(self, handlers: Mapping[int, Callable[[CommandIn], CommandOutcome]]) -> None:
        """Commands a firmware personality handles its own way (same ACK, retransmission and refusal rules)."""
        self._handlers.update(handlers)

    def handle(self, cmd: CommandIn, sender: tuple[object, ...], now_ns: int) -> CommandOutcome:
        """Run one command from ``sender`` (origin address and ids) at ``now_ns`` on the sender's clock (sim time
        for a mission, the wall clock for a ground station): it tells a retransmission from a new command."""
        last = self._last.get(sender)
        if last is not None and last[0] == cmd.key and now_ns - last[1] < RETRANSMIT_WINDOW_NS:
            retransmit = cmd.confirmation > 0 or (cmd.frame is not None and now_ns - last[1] < 1_000_000_000)
            if retransmit and cmd.command not in (CMD_REQUEST_MESSAGE, CMD_REQUEST_AUTOPILOT_CAPABILITIES):
                prev = last[2]
                return CommandOutcome(prev.result, [], False, True)
        handler = self._handlers.get(cmd.command)
        if handler is None:
            out = CommandOutcome(CommandResult.unsupported(""))
        else:
            out = handler(cmd)
        self._last[sender] = (cmd.key, now_ns, out)
        return out

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def _mode_cmd(result: CommandResult) -> CommandOutcome:
        return CommandOutcome(result, mode_or_arming_changed=result.ok)

    def _geo(
        self, cmd: CommandIn, honour_relative_frame: bool = True
    ) -> tuple[float | None, float | None, float | None] | str:
        """(lat, lon, alt AMSL) of params 5-7 (None = unset), or a reason they are invalid.

        ``honour_relative_frame=False``: the altitude is AMSL whatever the COMMAND_INT frame says (DO_ORBIT).
        """
        p = cmd.params
        if cmd.frame is None:
            lat = p[4] if is_set(p[4]) else None
            lon = p[5] if is_set(p[5]) else None
        else:
            lat = None if int(p[4]) in _INT_UNSET else p[4] * 1e-7
            lon = None if int(p[5]) in _INT_UNSET else p[5] * 1e-7
        alt = p[6] if is_set(p[6]) else None
        for name, v in (("latitude", lat), ("longitude", lon), ("altitude", alt)):
            if v is not None and not math.isfinite(v):
                return f"{name} {v} is not finite"
        if lat is not None and abs(lat) > 90.0:
            return f"latitude {lat} outside [-90, 90]"
        if lon is not None and abs(lon) > 180.0:
            return f"longitude {lon} outside [-180, 180]"
        if cmd.frame is not None and cmd.frame not in _GLOBAL_FRAMES:
            return f"frame {cmd.frame} not supported (use GLOBAL_INT or GLOBAL_RELATIVE_ALT_INT)"
        relative = cmd.frame in (MavFrame.GLOBAL_RELATIVE_ALT, MavFrame.GLOBAL_RELATIVE_ALT_INT)
        if alt is not None and relative and honour_relative_frame:
            home = self.api.telemetry.state().home
            if home is None:
                return "altitude relative to home given but there is no home position yet"
            alt += home.alt_amsl_m
        return (lat, lon, alt)

    # ------------------------------------------------------------------ commands
    def _arm(self, cmd: CommandIn) -> CommandOutcome:
        p1, p2 = cmd.params[0], cmd.params[1]
        force = p2 == FORCE_MAGIC
        if p1 == 1.0:
            return self._mode_cmd(self.api.action.arm(force))
        if p1 == 0.0:
            return self._mode_cmd(self.api.action.disarm(force))
        return CommandOutcome(CommandResult.denied(f"ARM_DISARM param1 must be 1 (arm) or 0 (disarm), got {p1}"))

    def _takeoff(self, cmd: CommandIn) -> CommandOutcome:
        alt_amsl = cmd.params[6]
        if not is_set(alt_amsl):
            return self._mode_cmd(self.api.action.takeoff(None))
        if not math.isfinite(alt_amsl):
            return CommandOutcome(CommandResult.denied(f"Takeoff denied: altitude {alt_amsl} is not finite"))
        home = self.api.telemetry.state().home
        if home is None:
            return CommandOutcome(
                CommandResult.rejected("Takeoff rejected: an AMSL altitude needs a home position (arm first)")
            )
        rel = alt_amsl - home.alt_amsl_m
        least = float(self.api.params.get("MIS_TAKEOFF_ALT"))
        if rel >= least:
            return self._mode_cmd(self.api.action.takeoff(rel))
        # below home + MIS_TAKEOFF_ALT (MAVProxy's `takeoff 10` sends 10 m AMSL): PX4's navigator raises it
        r = self.api.action.takeoff(least)
        notice = f"Using minimum takeoff altitude: {least:.2f} m" if r.ok else ""
        return CommandOutcome(r, mode_or_arming_changed=r.ok, notice=notice)

    def _do_set_mode(self, cmd: CommandIn) -> CommandOutcome:
        base, main, sub = cmd.params[0], cmd.params[1], cmd.params[2]
        return self._mode_cmd(self.set_mode_px4(base, main, sub))

    def set_mode_px4(self, base: float, main: float, sub: float) -> CommandResult:
        """DO_SET_MODE and the SET_MODE message: PX4 custom (main, sub) modes only."""
        if not all(math.isfinite(v) and v >= 0 for v in (base, main, sub)):
            return CommandResult.denied(f"set mode: invalid parameters ({base}, {main}, {sub})")
        if not int(base) & mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return CommandResult.denied("set mode: only PX4 custom modes are supported (set CUSTOM_MODE_ENABLED)")
        mode = FlightMode.from_px4(int(main), int(sub))
        if mode is None:
            return CommandResult.denied(f"set mode: PX4 mode main {int(main)} sub {int(sub)} is not available")
        return self.api.action.set_mode(mode)

    def _reposition(self, cmd: CommandIn) -> CommandOutcome:
        geo = self._geo(cmd)
        if isinstance(geo, str):
            return CommandOutcome(CommandResult.denied(f"Reposition denied: {geo}"))
        speed, yaw = cmd.params[0], cmd.params[3]
        if is_set(yaw) and not math.isfinite(yaw):
            return CommandOutcome(CommandResult.denied(f"Reposition denied: yaw {yaw} is not finite"))
        result = self.api.action.reposition(geo[0], geo[1], geo[2], yaw if is_set(yaw) else None)
        if result.ok and math.isfinite(speed) and speed > 0:
            self.api.action.change_speed(speed)
        return self._mode_cmd(result)

    def _mission_start(self, cmd: CommandIn) -> CommandOutcome:
        first = cmd.params[0]
        if is_set(first) and (not math.isfinite(first) or first < 0):
            return CommandOutcome(CommandResult.denied(f"Mission start denied: first item {first} is invalid"))
        if is_set(first) and first > 0:
            r = self.api.mission.set_current(int(first))
            if not r.ok:
                return CommandOutcome(r)
        return self._mode_cmd(self.api.mission.start())

    def _set_mission_current(self, cmd: CommandIn) -> CommandOutcome:
        """224: param1 the item (-1 = keep), param2 1 = reset the mission (start again from item 0)."""
        seq, reset = cmd.params[0], cmd.params[1]
        if not math.isfinite(seq) or (seq < 0 and seq != -1):
            return CommandOutcome(CommandResult.denied(f"Set mission current denied: item {seq} is invalid"))
        if reset == 1.0 and seq == -1:
            seq = 0.0
        if seq == -1:
            return CommandOutcome(CommandResult.accepted())
        return CommandOutcome(self.api.mission.set_current(int(seq)))

    def _change_speed(self, cmd: CommandIn) -> CommandOutcome:
        speed = cmd.params[1]
        if speed == -1.0 or speed == -2.0:  # -1 no change, -2 return to default (not tracked separately)
            return CommandOutcome(CommandResult.accepted())
        if not math.isfinite(speed):
            return CommandOutcome(CommandResult.denied(f"Change speed denied: speed {speed} is not finite"))
        return CommandOutcome(self.api.action.change_speed(speed))

    def _orbit(self, cmd: CommandIn) -> CommandOutcome:
        radius, velocity = cmd.params[0], cmd.params[1]
        if not math.isfinite(radius):
            return CommandOutcome(CommandResult.denied(f"Orbit denied: radius {radius} is not finite"))
        if not is_set(velocity):
            velocity = 1.0  # PX4's default orbit speed
        if not math.isfinite(velocity):
            return CommandOutcome(CommandResult.denied(f"Orbit denied: velocity {velocity} is not finite"))
        # MAVSDK's do_orbit(absolute_altitude_m) puts an AMSL altitude into a GLOBAL_RELATIVE_ALT COMMAND_INT,
        # and PX4's orbit takes param 7 as AMSL whatever the frame: so do we (else the vehicle climbs away)
        geo = self._geo(cmd, honour_relative_frame=False)
        if isinstance(geo, str):
            return CommandOutcome(CommandResult.denied(f"Orbit denied: {geo}"))
        return self._mode_cmd(self.api.action.orbit(radius, velocity, geo[0], geo[1], geo[2]))

    def _set_home(self, cmd: CommandIn) -> CommandOutcome:
        if cmd.params[0] == 1.0:
            return CommandOutcome(self.api.action.set_home(None))
        geo = self._geo(cmd)
        if isinstance(geo, str):
            return CommandOutcome(CommandResult.denied(f"Set home denied: {geo}"))
        lat, lon, alt = geo
        if lat is None or lon is None or alt is None:
            return CommandOutcome(CommandResult.denied("Set home denied: latitude, longitude and altitude required"))
        return CommandOutcome(self.api.action.set_home(GeoPoint(lat, lon, alt)))

    def _gripper(self, cmd: CommandIn) -> CommandOutcome:
        """DO_GRIPPER: param 1 the instance, param 2 GRIPPER_ACTION_RELEASE (0) or _GRAB (1)."""
        gripper = self.api.gripper
        if gripper is None:
            return CommandOutcome(CommandResult.unsupported("this vehicle has no gripper"))
        instance, action = cmd.params[0], cmd.params[1]
        if not math.isfinite(instance) or instance != int(instance):
            return CommandOutcome(CommandResult.denied(f"gripper instance {instance} is not a whole number"))
        if action == mavlink2.GRIPPER_ACTION_GRAB:
            return CommandOutcome(gripper.grab(int(instance)))
        if action == mavlink2.GRIPPER_ACTION_RELEASE:
            return CommandOutcome(gripper.release(int(instance)))
        return CommandOutcome(CommandResult.denied(f"gripper action {action} is neither release (0) nor grab (1)"))

    def _inject_failure(self, cmd: CommandIn) -> CommandOutcome:
        if int(self.api.params.get("SYS_FAILURE_EN")) != 1:
            return CommandOutcome(CommandResult.denied("Failure injection disabled: set SYS_FAILURE_EN to 1"))
        unit, kind, instance = cmd.params[0], cmd.params[1], cmd.params[2]
        if not all(math.isfinite(v) and v >= 0 for v in (unit, kind, instance)):
            return CommandOutcome(CommandResult.denied("Failure injection denied: invalid unit/type/instance"))
        failure = self.api.failure
        if failure is None:
            return CommandOutcome(CommandResult.unsupported("failure injection is not implemented by this autopilot"))
        return CommandOutcome(failure.inject(int(unit), int(kind), int(instance)))

    def _set_message_interval(self, cmd: CommandIn) -> CommandOutcome:
        msg_id, interval_us = cmd.params[0], cmd.params[1]
        if not (math.isfinite(msg_id) and math.isfinite(interval_us)) or msg_id < 0:
            return CommandOutcome(CommandResult.denied("SET_MESSAGE_INTERVAL with invalid parameters"))
        if not self.set_interval(int(msg_id), interval_us):
            return CommandOutcome(CommandResult.unsupported(f"message {int(msg_id)} cannot be streamed"))
        return CommandOutcome(CommandResult.accepted())

    def _request_message(self, cmd: CommandIn) -> CommandOutcome:
        msg_id = cmd.params[0]
        if not math.isfinite(msg_id) or msg_id < 0:
            return CommandOutcome(CommandResult.denied(f"REQUEST_MESSAGE: invalid message id {msg_id}"))
        return self._send_message(int(msg_id))

    def _send_message(self, msg_id: int) -> CommandOutcome:
        msg = self.request_message(msg_id)
        if msg is None:
            return CommandOutcome(CommandResult.unsupported(""))
        if isinstance(msg, str):  # known but not available now ('' = nothing worth a STATUSTEXT)
            return CommandOutcome(CommandResult(Result.TEMPORARILY_REJECTED, msg))
        return CommandOutcome(CommandResult.accepted(), [msg])
