"""The ArduCopter personality: identity, modes, commands and streams of ArduCopter over the flight core.

What DroneKit, MAVProxy and pymavlink scripts written for ArduPilot rely on (facts in docs/mavlink.md,
"What clients expect", the ArduCopter dialect):

- HEARTBEAT autopilot ARDUPILOTMEGA, custom_mode = the ArduCopter mode number (:mod:`.modes`); DO_SET_MODE
  (param2 = mode number) and SET_MODE; unsupported modes refused with a reason.
- Arming only in ArduCopter's armable modes; refusals and a report every 30 s while disarmed as
  ``PreArm: <reason>`` STATUSTEXT (``ARMING_CHECK`` = 0 skips the checks).
- NAV_TAKEOFF in GUIDED to an altitude **relative to home**; GUIDED targets (:mod:`.guided`);
  CONDITION_YAW, DO_SET_ROI (the nose follows the point), DO_CHANGE_SPEED (generic).
- Streams by group at the ``SRx_*`` rates, set by REQUEST_DATA_STREAM (:mod:`.streams`), with
  EKF_STATUS_REPORT (DroneKit's ``is_armable`` needs it).
- Missions with item 0 = home, float MISSION_ITEM / MISSION_REQUEST as well as the _INT forms
  (:mod:`.adapter`); ArduPilot parameter names (:mod:`.params`); AUTOPILOT_VERSION as ArduCopter 4.5.7.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping

from pymavlink.dialects.v20 import ardupilotmega as apm
from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import (
    CommandResult,
    FlightMode,
    MavFrame,
    Severity,
    StatusText,
    VehicleState,
)
from harness.autopilot.mavlink.ardupilot.adapter import CopterSystem, copter_text
from harness.autopilot.mavlink.ardupilot.guided import (
    RELATIVE_GLOBAL,
    Goto,
    attitude_target,
    geo_of_local,
    global_point,
    global_target,
    local_target,
    mission_item_goto,
)
from harness.autopilot.mavlink.ardupilot.modes import (
    ALT_HOLDING,
    ARMABLE,
    ATTITUDE_TARGETS,
    CORE_MODE,
    STICK_CORE_MODE,
    SUPPORTED,
    USER_TAKEOFF,
    CopterMode,
    ModeTracker,
    copter_mode,
)
from harness.autopilot.mavlink.ardupilot.params import CopterParams
from harness.autopilot.mavlink.ardupilot.rc import CHANNELS, RcInput
from harness.autopilot.mavlink.ardupilot.streams import (
    DATA_STREAM_GROUPS,
    GROUP_MESSAGES,
    MAX_RATE_HZ,
    SENSOR_BUILDERS,
    ekf_status_report,
    rc_builders,
)
from harness.autopilot.mavlink.commands import FORCE_MAGIC, CommandIn, CommandOutcome
from harness.autopilot.mavlink.dialect_api import Component, DialectHost
from harness.autopilot.mavlink.messages import MAVLinkMessage, Origin, Out, is_set
from harness.autopilot.mavlink.mission_items import ardupilot_item_result
from harness.autopilot.mavlink.telemetry import SENSOR_GEOFENCE, Builder, sys_status
from harness.autopilot.params import Params
from harness.autopilot.services import System
from harness.autopilot.validate import finite
from harness.core.geo import flat_offset_m

log = logging.getLogger(__name__)

_M = mavlink2
CMD_CONDITION_YAW = 115
CMD_DO_SET_ROI = 201
CMD_DO_SET_ROI_LOCATION = 195
CMD_DO_SET_ROI_NONE = 197
PREARM_REPORT_NS = 30_000_000_000
"""ArduPilot repeats its failing pre-arm check every 30 s while disarmed ..."""
PREARM_FIRST_NS = 3_000_000_000
"""... and the first report waits for 3 s of sim time (sensors and estimator starting up: no IMU data yet at t=0)."""

CAPABILITIES = (
    _M.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | _M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | _M.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | _M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | _M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | _M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
    | _M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | _M.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
    | _M.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
    | _M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
)
FLIGHT_SW_VERSION = (4 << 24) | (5 << 16) | (7 << 8) | 255
"""Reported as ArduCopter 4.5.7 (official release)."""
BOOT_BANNER = "ArduCopter V4.5.7"
WPNAV_SPEED_MIN_CM_S = 20.0
"""AC_WPNav ignores a horizontal speed below this."""
_LINK_SR = {"tcp": 0, "api": 1, "gcs": 2}
"""Which ``SRx_`` set a REQUEST_DATA_STREAM on a link writes (SERIAL0 = the TCP link)."""
_AUTO_FLAG_MODES = frozenset({CopterMode.AUTO, CopterMode.GUIDED, CopterMode.RTL, CopterMode.CIRCLE, CopterMode.LAND})


class CopterDialect:
    """One ArduCopter vehicle's dialect (see :mod:`harness.autopilot.mavlink.personality`)."""

    mission_float_form = True
    param_bytewise = False
    components: Mapping[int, Component] = {}

    def __init__(self, core: System, sysid: int) -> None:
        self._core = core
        self.params = CopterParams(core.params, sysid)
        self.own_params: Params | None = self.params
        self.api: System = CopterSystem(core, self.params)
        self.modes = ModeTracker()
        self.rc = RcInput(self.params)
        self.builders: Mapping[int, Builder] = {
            apm.MAVLINK_MSG_ID_EKF_STATUS_REPORT: ekf_status_report,
            _M.MAVLINK_MSG_ID_SYS_STATUS: self._sys_status,
            **SENSOR_BUILDERS,
            **rc_builders(self.rc),
        }
        self.stream_defaults: Mapping[int, int] = self._intervals()
        self._host: DialectHost | None = None
        self._yaw_hold: float | None = None
        self._yaw_core_mode: FlightMode | None = None
        self._roi: tuple[float, float, float] | None = None
        self._prearm_next_ns = 0
        self._boot_texts: list[str] = []
        """What ArduCopter says when it boots, sent after a reboot."""
        self._armed_at_t_ns: int | None = None
        """Sim time of the state snapshot when an ARM was accepted (the snapshot shows it from the next tick)."""
        self.params.subscribe(self._param_changed)
        self._rc_timeout_to_core()

    def bind(self, host: DialectHost, mav: mavlink2.MAVLink, sysid: int) -> None:
        self._host = host

    # ------------------------------------------------------------------ identity
    def check_mission_item(self, m: MAVLinkMessage) -> tuple[int, str]:
        return ardupilot_item_result(m)

    busy = False
    """Nothing of ArduCopter's own goes on over several ticks."""

    def heartbeat(self, mav: mavlink2.MAVLink, state: VehicleState) -> MAVLinkMessage:
        shown = self.modes.shown(state.mode)
        base = _M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | _M.MAV_MODE_FLAG_STABILIZE_ENABLED
        if shown in _AUTO_FLAG_MODES:
            base |= _M.MAV_MODE_FLAG_GUIDED_ENABLED
        if state.armed:
            base |= _M.MAV_MODE_FLAG_SAFETY_ARMED
        status = _M.MAV_STATE_ACTIVE if state.armed else _M.MAV_STATE_STANDBY
        if state.failsafe:
            status = _M.MAV_STATE_CRITICAL
        return mav.heartbeat_encode(_M.MAV_TYPE_QUADROTOR, _M.MAV_AUTOPILOT_ARDUPILOTMEGA, base, int(shown), status, 3)

    def autopilot_version(self, mav: mavlink2.MAVLink, sysid: int) -> MAVLinkMessage:
        return mav.autopilot_version_encode(
            CAPABILITIES,
            FLIGHT_SW_VERSION,
            0,
            0,
            0,
            [0] * 8,
            [0] * 8,
            [0] * 8,
            0,
            0,
            0x4841524E45535300 | sysid,
            [0] * 18,
        )

    def _sys_status(self, mav: mavlink2.MAVLink, state: VehicleState, t_ms: int) -> MAVLinkMessage:
        """SYS_STATUS with the geofence *enabled* only when FENCE_ENABLE = 1 (MAVProxy says "fence enabled")."""
        msg = sys_status(mav, state, t_ms)
        if int(self.params["FENCE_ENABLE"]) != 1:
            msg.onboard_control_sensors_enabled &= ~SENSOR_GEOFENCE
        return msg

    # ------------------------------------------------------------------ streams
    def _intervals(self) -> dict[int, int]:
        out: dict[int, int] = {}
        for group, ids in GROUP_MESSAGES.items():
            hz = self.params.stream_hz(group)
            if hz > 0:
                for i in ids:
                    out[i] = min(out.get(i, 1 << 62), round(1e9 / hz))
        return out

    def _param_changed(self, name: str, _value: float) -> None:
        if name == "RC_OVERRIDE_TIME":
            self._rc_timeout_to_core()
        if name.startswith("SR") and self._host is not None:
            new = self._intervals()
            for ids in GROUP_MESSAGES.values():
                for i in ids:
                    ns = new.get(i)
                    if self._host.streams.interval_us(i) * 1000 != (ns if ns is not None else -1000):
                        self._host.streams.set_interval(i, -1 if ns is None else ns / 1000)

    def _request_data_stream(self, m: MAVLinkMessage, origin: Origin) -> None:
        groups = DATA_STREAM_GROUPS.get(m.req_stream_id)
        if groups is None:
            return
        host = self._host
        name = host.link_name(origin.link) if host is not None else "api"
        x = _LINK_SR.get(name, 1)
        rate = min(float(m.req_message_rate), MAX_RATE_HZ) if m.start_stop else 0.0
        for g in groups:
            self.params.set(f"SR{x}_{g}", rate)

    # ------------------------------------------------------------------ modes
    def set_copter_mode(self, number: float) -> CommandResult:
        mode = copter_mode(number)
        if mode is None:
            return CommandResult.denied(f"Mode change failed: {number} is not an ArduCopter mode")
        if mode not in SUPPORTED:
            names = ", ".join(m.name for m in sorted(SUPPORTED))
            return CommandResult.denied(f"Mode change to {mode.name} failed: not flown here (modes: {names})")
        st = self.api.telemetry.state()
        if mode == self.modes.shown(st.mode):
            return CommandResult.accepted()
        rc_live = self.rc.any_active(st.t_ns)
        if self.rc.received:
            self._core_rc(rc_live)
        if mode in STICK_CORE_MODE and rc_live:  # a pilot: the mode flies on the sticks
            self._sticks(st, mode)
            r = self.api.action.set_mode(STICK_CORE_MODE[mode])
        elif mode is CopterMode.STABILIZE:
            if st.armed and st.in_air:
                return CommandResult.denied("Mode change to STABILIZE failed: it needs RC input, none is configured")
            r = self.api.action.hold()
        elif mode is CopterMode.CIRCLE:
            r = self._circle(st)
        else:
            r = self.api.action.set_mode(CORE_MODE[mode])
        if not r.ok:
            return CommandResult(r.result, f"Mode change to {mode.name} failed: {r.reason}")
        self.modes.select(mode)
        self._yaw_hold, self._roi = None, None
        return r

    def _circle(self, st: VehicleState) -> CommandResult:
        """ArduCopter's CIRCLE: around a point CIRCLE_RADIUS ahead of the nose, at CIRCLE_RATE."""
        radius = self.params["CIRCLE_RADIUS"] / 100.0
        rate = self.params["CIRCLE_RATE"]
        if radius < 1.0:
            return CommandResult.denied("CIRCLE_RADIUS below 1 m (100 cm) is not flown here")
        n, e, d = st.pos_ned_m
        lat, lon, _ = geo_of_local(st, (n + radius * math.cos(st.yaw_rad), e + radius * math.sin(st.yaw_rad), d))
        speed = abs(math.radians(rate)) * radius
        return self.api.action.orbit(radius if rate >= 0 else -radius, max(speed, 0.1), lat, lon, st.alt_amsl_m)

    # ------------------------------------------------------------------ RC input
    def _rc_timeout_to_core(self) -> None:
        """The core's stick time-out is ArduCopter's override time-out (a negative one never ends: the core's
        longest)."""
        t = self.params["RC_OVERRIDE_TIME"]
        core = self.params.core
        v = 35.0 if t < 0 else min(t, 35.0)
        if "COM_RC_LOSS_T" in core and core["COM_RC_LOSS_T"] != v:
            core.set("COM_RC_LOSS_T", v)

    def _core_rc(self, live: bool) -> None:
        """Sticks count for the core (COM_RC_IN_MODE 1) once RC input came; 4 (none) otherwise."""
        core = self.params.core
        want = 1 if live else 4
        if "COM_RC_IN_MODE" in core and int(core["COM_RC_IN_MODE"]) != want:
            core.set("COM_RC_IN_MODE", want)

    def _sticks(self, st: VehicleState, mode: CopterMode) -> None:
        manual = self.api.manual_control
        if manual is not None:
            manual.set_sticks(*self.rc.sticks(st.t_ns, mode in ALT_HOLDING))

    def _rc_override(self, m: MAVLinkMessage, origin: Origin) -> None:
        """RC_CHANNELS_OVERRIDE (``rc.py``): in a pilot mode the sticks fly the vehicle; a released channel reads
        the radio again at once (SITL's: throttle low)."""
        st = self.api.telemetry.state()
        values = [int(getattr(m, f"chan{i}_raw", 0xFFFF if i <= 8 else 0)) for i in range(1, CHANNELS + 1)]
        if not self.rc.override(origin.sysid, values, st.t_ns):
            return
        live = self.rc.any_active(st.t_ns)
        shown = self.modes.shown(st.mode)
        if shown not in STICK_CORE_MODE:
            self._core_rc(live)
            return
        if not live and not st.in_air:  # every channel released on the ground: the mode flies without a pilot
            if st.mode is STICK_CORE_MODE[shown]:
                r = (
                    self.api.action.hold()
                    if shown is CopterMode.STABILIZE
                    else self.api.action.set_mode(CORE_MODE[shown])
                )
                if not r.ok:
                    log.info("vehicle %d: RC released in %s: %s", self.api.vehicle, shown.name, r.reason)
            self._core_rc(False)
            return
        self._core_rc(True)
        self._sticks(st, shown)
        core_mode = STICK_CORE_MODE[shown]
        if st.mode is not core_mode:
            r = self.api.action.set_mode(core_mode)
            if not r.ok:
                log.info("vehicle %d: RC override in %s: %s", self.api.vehicle, shown.name, r.reason)

    # ------------------------------------------------------------------ commands
    def command_handlers(self) -> Mapping[int, Callable[[CommandIn], CommandOutcome]]:
        return {
            _M.MAV_CMD_DO_SET_MODE: self._do_set_mode,
            _M.MAV_CMD_COMPONENT_ARM_DISARM: self._arm,
            _M.MAV_CMD_NAV_TAKEOFF: self._takeoff,
            CMD_CONDITION_YAW: self._condition_yaw,
            CMD_DO_SET_ROI: self._set_roi,
            CMD_DO_SET_ROI_LOCATION: self._set_roi,
            CMD_DO_SET_ROI_NONE: lambda c: self._roi_none(),
            _M.MAV_CMD_DO_REPOSITION: self._reposition,
            _M.MAV_CMD_DO_CHANGE_SPEED: self._change_speed,
            _M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: self._reboot,
        }

    def _change_speed(self, cmd: CommandIn) -> CommandOutcome:
        """DO_CHANGE_SPEED as ArduCopter takes it: param2 > 0 m/s, else FAILED; param1 2 / 3 climb / descent
        speed (accepted, not flown: the core has no separate one), else the horizontal speed, which any value
        sets (below WPNAV's 20 cm/s minimum it is ignored); the core flies at most its MPC_XY_VEL_MAX."""
        kind, speed = cmd.params[0], cmd.params[1]
        if not (math.isfinite(speed) and speed > 0.0):
            return CommandOutcome(CommandResult.failed(f"Change speed failed: speed {speed} m/s is not above 0"))
        if math.isfinite(kind) and kind > 1.9:
            return CommandOutcome(CommandResult.accepted())
        if speed * 100.0 < WPNAV_SPEED_MIN_CM_S:
            return CommandOutcome(CommandResult.accepted())
        core = self.params.core
        flown = min(speed, core["MPC_XY_VEL_MAX"]) if "MPC_XY_VEL_MAX" in core else speed
        if flown != speed:
            log.info(
                "vehicle %d: DO_CHANGE_SPEED %g m/s flies at %g m/s (MPC_XY_VEL_MAX)", self.api.vehicle, speed, flown
            )
        r = self.api.action.change_speed(flown)
        return CommandOutcome(r if r.ok else CommandResult.failed(f"Change speed failed: {r.reason}"))

    def _reboot(self, cmd: CommandIn) -> CommandOutcome:
        """PREFLIGHT_REBOOT_SHUTDOWN param1 1 (or 3, to the bootloader): on the ground and disarmed, the flight
        stack restarts in place (``Autopilot.reboot``), in STABILIZE, and says so as ArduCopter boots."""
        if cmd.params[0] not in (1.0, 3.0):
            return CommandOutcome(CommandResult.unsupported("Reboot: only param1 = 1 (reboot the autopilot) is done"))
        r = self.api.action.reboot()
        if not r.ok:
            return CommandOutcome(r)
        self.modes = ModeTracker()
        self.rc.reset()
        self._yaw_hold = self._roi = self._yaw_core_mode = None
        self._armed_at_t_ns = None
        self._prearm_next_ns = 0
        self._boot_texts = [BOOT_BANNER, "Frame: QUAD/X"]
        return CommandOutcome(r, mode_or_arming_changed=True)

    def _reposition(self, cmd: CommandIn) -> CommandOutcome:
        """DO_REPOSITION (COMMAND_INT) as ArduCopter takes it: a goto in GUIDED; from another mode only with
        the change-mode flag (param2 bit 0), which switches to GUIDED first. param1 > 0 sets the speed."""
        relative = RELATIVE_GLOBAL.get(MavFrame(cmd.frame)) if cmd.frame in set(MavFrame) else None
        if relative is None:
            return CommandOutcome(CommandResult.denied("DO_REPOSITION: send it as COMMAND_INT in a global frame"))
        st = self.api.telemetry.state()
        changed = False
        if self.modes.shown(st.mode) is not CopterMode.GUIDED:
            if not (math.isfinite(cmd.params[1]) and int(cmd.params[1]) & 1):
                return CommandOutcome(CommandResult.denied("DO_REPOSITION: not in GUIDED (set the change-mode flag)"))
            r = self.set_copter_mode(CopterMode.GUIDED)
            if not r.ok:
                return CommandOutcome(r)
            changed = True
        point = global_point(cmd.params[4] * 1e-7, cmd.params[5] * 1e-7, cmd.params[6], relative, st)
        if isinstance(point, str):
            return CommandOutcome(CommandResult.denied(f"DO_REPOSITION: {point}"), mode_or_arming_changed=changed)
        r = self._goto(Goto(*point))
        speed = cmd.params[0]
        if r.ok and math.isfinite(speed) and speed > 0:
            self.api.action.change_speed(speed)
        return CommandOutcome(r, mode_or_arming_changed=changed)

    def _do_set_mode(self, cmd: CommandIn) -> CommandOutcome:
        r = self.set_copter_mode(cmd.params[1])
        return CommandOutcome(r, mode_or_arming_changed=r.ok)

    def _arm(self, cmd: CommandIn) -> CommandOutcome:
        p1, force = cmd.params[0], cmd.params[1] == FORCE_MAGIC
        if p1 == 0.0:
            r = self.api.action.disarm(force)
            return CommandOutcome(r, mode_or_arming_changed=r.ok)
        if p1 != 1.0:
            return CommandOutcome(CommandResult.denied(f"ARM_DISARM param1 must be 1 (arm) or 0 (disarm), got {p1}"))
        st = self.api.telemetry.state()
        if st.armed:
            return CommandOutcome(CommandResult.accepted())
        checks = int(self.params["ARMING_CHECK"]) != 0 and not force
        shown = self.modes.shown(st.mode)
        if checks and shown not in ARMABLE:
            return CommandOutcome(CommandResult.denied("Arm: Mode not armable"))
        r = self.api.action.arm(not checks)
        if not r.ok:
            r = CommandResult(r.result, copter_text_reason(r.reason))
        self._armed_at_t_ns = st.t_ns if r.ok else None
        return CommandOutcome(r, mode_or_arming_changed=r.ok)

    def _takeoff(self, cmd: CommandIn) -> CommandOutcome:
        alt = cmd.params[6]
        st = self.api.telemetry.state()
        if not (st.armed or st.t_ns == self._armed_at_t_ns):  # armed, or just now (a takeoff may follow at once)
            return CommandOutcome(CommandResult.denied("Takeoff: vehicle not armed"))
        shown = self.modes.shown(st.mode)
        if shown not in USER_TAKEOFF:
            return CommandOutcome(CommandResult.denied(f"Takeoff: not in GUIDED mode (mode {shown.name})"))
        if st.in_air:
            return CommandOutcome(CommandResult.denied("Takeoff: already flying"))
        if not math.isfinite(alt) or alt <= 0.0:
            return CommandOutcome(CommandResult.denied(f"Takeoff: altitude {alt} m above home is not valid"))
        r = self.api.action.takeoff(alt)  # relative to home, as ArduCopter reads param 7
        return CommandOutcome(r, mode_or_arming_changed=r.ok)

    def _condition_yaw(self, cmd: CommandIn) -> CommandOutcome:
        angle, _speed, direction, relative = cmd.params[:4]
        if not finite([angle, direction, relative]):
            return CommandOutcome(CommandResult.denied("CONDITION_YAW with NaN or infinite parameters"))
        st = self.api.telemetry.state()
        yaw = math.radians(angle)
        if relative:
            yaw = st.yaw_rad + (-yaw if direction < 0 else yaw)
        r = self._set_yaw(yaw)
        if r.ok:
            self._yaw_hold, self._roi, self._yaw_core_mode = yaw, None, st.mode
        return CommandOutcome(r)

    def _set_yaw(self, yaw: float | None) -> CommandResult:
        return self.api.action.set_yaw(yaw)

    def _set_roi(self, cmd: CommandIn) -> CommandOutcome:
        p = cmd.params
        if cmd.frame is None:
            lat, lon = p[4], p[5]
        else:
            lat, lon = p[4] * 1e-7, p[5] * 1e-7
        alt = p[6] if is_set(p[6]) else 0.0
        if not finite([lat, lon, alt]) or abs(lat) > 90 or abs(lon) > 180:
            return CommandOutcome(CommandResult.denied("DO_SET_ROI: invalid location"))
        if lat == 0.0 and lon == 0.0:
            return self._roi_none()
        self._roi = (lat, lon, alt)
        self._yaw_hold = None
        return CommandOutcome(CommandResult.accepted())

    def _roi_none(self) -> CommandOutcome:
        self._roi = None
        self._set_yaw(None)
        return CommandOutcome(CommandResult.accepted())

    # ------------------------------------------------------------------ messages of its own
    def handle(self, m: MAVLinkMessage, origin: Origin, now: int) -> list[Out] | None:
        mid = m.get_msgId()
        host = self._host
        if mid == _M.MAVLINK_MSG_ID_SET_MODE:
            r = self.set_copter_mode(m.custom_mode)
            if host is not None:
                if r.ok:
                    host.heartbeat.force()
                elif r.reason:
                    host.say(Severity.WARNING, r.reason, now)
            return []
        if mid == _M.MAVLINK_MSG_ID_REQUEST_DATA_STREAM:
            self._request_data_stream(m, origin)
            return []
        if mid in (_M.MAVLINK_MSG_ID_MISSION_ITEM, _M.MAVLINK_MSG_ID_MISSION_ITEM_INT) and m.current in (2, 3):
            return self._guided_item(m, origin, now)
        if mid in (_M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED, _M.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT):
            self._position_target(m, now)
            return []
        if mid == _M.MAVLINK_MSG_ID_RC_CHANNELS_OVERRIDE:
            self._rc_override(m, origin)
            return []
        if mid == _M.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET:
            self._attitude_target(m, now)
            return []
        return None

    def _attitude_target(self, m: MAVLinkMessage, now: int) -> None:
        """SET_ATTITUDE_TARGET in GUIDED and GUIDED_NOGPS (:func:`.guided.attitude_target`); ignored elsewhere,
        as ArduCopter does. It runs on the core's offboard control, which stops after GUID_TIMEOUT without one."""
        st = self.api.telemetry.state()
        if self.modes.shown(st.mode) not in ATTITUDE_TARGETS:
            log.debug("vehicle %d: attitude target ignored outside GUIDED", self.api.vehicle)
            return
        p = self.params
        sp = attitude_target(m, st, p["WPNAV_SPEED_UP"] / 100.0, p["WPNAV_SPEED_DN"] / 100.0)
        if isinstance(sp, str):
            r = CommandResult.denied(sp)
        else:
            r = self.api.offboard.set_axes(sp)
            if r.ok and st.mode is not FlightMode.OFFBOARD:
                r = self.api.action.set_mode(FlightMode.OFFBOARD)
        if not r.ok and r.reason and self._host is not None:
            self._host.say(Severity.WARNING, r.reason, now)

    def _guided_item(self, m: MAVLinkMessage, origin: Origin, now: int) -> list[Out]:
        st = self.api.telemetry.state()
        code = _M.MAV_MISSION_ACCEPTED
        reason = ""
        if self.modes.shown(st.mode) is not CopterMode.GUIDED:
            code, reason = _M.MAV_MISSION_ERROR, "Guided waypoint refused: not in GUIDED mode"
        else:
            goto = mission_item_goto(m, st)
            r = self._goto(goto) if isinstance(goto, Goto) else CommandResult.denied(goto)
            if not r.ok:
                code, reason = _M.MAV_MISSION_ERROR, f"Guided waypoint refused: {r.reason}"
        if reason and self._host is not None:
            self._host.say(Severity.WARNING, reason, now)
        mav = self._mav_for_ack()
        if mav is None:
            return []
        ack = mav.mission_ack_encode(origin.sysid, origin.compid, code, m.mission_type)
        return [Out(ack, origin)]

    def _mav_for_ack(self) -> mavlink2.MAVLink | None:
        return self._host.mav if self._host is not None else None

    def _goto(self, goto: Goto) -> CommandResult:
        yaw = goto.yaw_rad if goto.yaw_rad is not None else self._yaw_hold
        return self.api.action.reposition(goto.lat_deg, goto.lon_deg, goto.alt_amsl_m, yaw)

    def _position_target(self, m: MAVLinkMessage, now: int) -> None:
        st = self.api.telemetry.state()
        if self.modes.shown(st.mode) is not CopterMode.GUIDED:
            log.debug("vehicle %d: position target ignored outside GUIDED", self.api.vehicle)
            return
        target = (
            local_target(m, st)
            if m.get_msgId() == _M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED
            else global_target(m, st)
        )
        if isinstance(target, str):
            if self._host is not None:
                self._host.say(Severity.WARNING, target, now)
            return
        if isinstance(target, Goto):
            r = self._goto(target)
        else:
            sp = target.setpoint
            if sp.yaw_rad is None and sp.yaw_rate_rad_s is None and self._yaw_hold is not None:
                sp = type(sp)(sp.position_m, sp.velocity_m_s, sp.accel_m_s2, self._yaw_hold, None, sp.frame)
            r = self.api.offboard.set_setpoint(sp)
            if r.ok and st.mode is not FlightMode.OFFBOARD:
                r = self.api.action.set_mode(FlightMode.OFFBOARD)
        if not r.ok and r.reason and self._host is not None:
            self._host.say(Severity.WARNING, r.reason, now)

    # ------------------------------------------------------------------ periodic
    def close(self) -> None:
        """Nothing held open: ArduCopter's services here keep no files."""

    def tick(self, state: VehicleState, now: int) -> list[Out]:
        if self._boot_texts and self._host is not None:
            for text in self._boot_texts:
                self._host.say(Severity.INFO, text, now)
            self._boot_texts = []
        if self._yaw_hold is not None and state.mode is not self._yaw_core_mode and state.in_air:
            self._yaw_core_mode = state.mode  # the core entered a mode (end of takeoff, velocity targets):
            self._set_yaw(self._yaw_hold)  # ArduCopter keeps the CONDITION_YAW heading within GUIDED
        if self._roi is not None and state.armed and state.in_air:
            lat, lon, _alt = self._roi
            dn, de = flat_offset_m(state.lat_deg, state.lon_deg, lat, lon)
            if math.hypot(dn, de) > 1.0:
                self._set_yaw(math.atan2(de, dn))
        booting = state.t_ns < PREARM_FIRST_NS
        if not state.armed and not booting and not state.health.preflight_ok and now >= self._prearm_next_ns:
            reason = self._core.telemetry.arming_check() if int(self.params["ARMING_CHECK"]) != 0 else ""
            if reason and self._host is not None:
                self._prearm_next_ns = now + PREARM_REPORT_NS
                self._host.say(Severity.CRITICAL, f"PreArm: {reason}", now)
        return []


def copter_text_reason(reason: str) -> str:
    """A core refusal in ArduPilot's words (``Arming denied: X`` -> ``PreArm: X``)."""
    return copter_text(StatusText(0, Severity.CRITICAL, reason)).text
