"""The MAVLink shell (SERIAL_CONTROL, device SERIAL_CONTROL_DEV_SHELL = 10), as PX4 offers its NuttShell over
MAVLink (MAVSDK ``shell``, QGroundControl's MAVLink console, PX4's ``mavlink_shell.py``).

Input is buffered until a newline, per client (its link and address: two consoles do not mix their
keystrokes); each line is echoed, executed, and answered with its output and the prompt ``nsh> ``, in
SERIAL_CONTROL replies (flags SERIAL_CONTROL_FLAG_REPLY, 70 bytes each) to the sender. A client's first
input also gets the banner. Replies from clients (flag REPLY) and other devices are ignored.

Bounded as NuttShell's line editor is: a line is at most ``LINE_MAX`` bytes (the rest of a longer one is
dropped and the line answered ``nsh: line too long``), at most ``LINES_PER_LOOP`` lines run per message or
server tick (more wait, up to ``PENDING_MAX``), and at most ``CLIENTS_MAX`` consoles are kept (the one
silent longest goes). A megabyte of input costs what its datagrams cost to read, not a stalled vehicle.

A small real command set, on the vehicle itself:

    help
    ver all | ver hw | ver git                        version lines
    param show [PATTERN]                              * wildcards; PX4's "x + NAME [i,j] : value" lines
    param set NAME VALUE | param get NAME             range-checked as PARAM_SET is
    param save | param load                           saved on every change already; load = the saved file
    commander arm [-f] | disarm [-f] | takeoff | land | status
    commander mode manual|altctl|posctl|stabilized|offboard|auto:mission|auto:loiter|auto:rtl|auto:takeoff|auto:land
    listener TOPIC [-n N]                             vehicle_status, vehicle_attitude, vehicle_local_position,
                                                      vehicle_global_position, battery_status, sensor_combined,
                                                      vehicle_gps_position, home_position, gimbal_device_attitude_status
    reboot                                            as MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN (``reboot.py``)
"""

from __future__ import annotations

import fnmatch
import math
import shlex
from collections import deque
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import CommandResult, FlightMode, VehicleState
from harness.autopilot.mavlink.messages import MAVLinkMessage, Origin, Out
from harness.autopilot.mavlink.parameters import ParamTable
from harness.autopilot.mavlink.service import Service
from harness.autopilot.mavlink.version import FLIGHT_SW_VERSION
from harness.autopilot.params import ParamType
from harness.autopilot.services import System

_M = mavlink2
CHUNK = 70
PROMPT = "nsh> "
BANNER = "\nNuttShell (NSH) uav-harness SITL\n"
_MODES = {
    "manual": FlightMode.MANUAL,
    "altctl": FlightMode.ALTCTL,
    "posctl": FlightMode.POSCTL,
    "stabilized": FlightMode.STABILIZED,
    "offboard": FlightMode.OFFBOARD,
    "auto:mission": FlightMode.MISSION,
    "auto:loiter": FlightMode.HOLD,
    "auto:rtl": FlightMode.RTL,
    "auto:takeoff": FlightMode.TAKEOFF,
    "auto:land": FlightMode.LAND,
}
TOPICS = (
    "vehicle_status",
    "vehicle_attitude",
    "vehicle_local_position",
    "vehicle_global_position",
    "battery_status",
    "sensor_combined",
    "vehicle_gps_position",
    "home_position",
    "gimbal_device_attitude_status",
)


VERSION = f"{FLIGHT_SW_VERSION >> 24}.{(FLIGHT_SW_VERSION >> 16) & 0xFF}.{(FLIGHT_SW_VERSION >> 8) & 0xFF}"


def _vec(v: tuple[float, ...] | None, fmt: str = "{:.4f}") -> str:
    return "[" + ", ".join(fmt.format(x) for x in v) + "]" if v is not None else "[]"


LINE_MAX = 256
"""Bytes of one command line (NuttShell's CONFIG_NSH_LINELEN is 64..80 on a flight controller)."""
LINES_PER_LOOP = 4
"""Command lines run per SERIAL_CONTROL message or server tick; more wait for the next ticks."""
PENDING_MAX = 16
"""Complete lines a console keeps waiting; more are dropped."""
CLIENTS_MAX = 8


class _Console:
    """One client's input: the line being typed (bounded) and the complete lines not run yet."""

    def __init__(self, origin: Origin) -> None:
        self.origin = origin
        self.started = False
        self.partial = bytearray()
        self.too_long = False
        self.lines: deque[str | None] = deque()
        """Complete lines to run; None for one that was too long."""

    def feed(self, data: bytes) -> None:
        while data:
            head, newline, data = data.partition(b"\n")
            if not self.too_long:
                self.partial += head
                if len(self.partial) > LINE_MAX:
                    self.too_long, self.partial = True, bytearray()
            if not newline:
                return
            if len(self.lines) < PENDING_MAX:
                text = self.partial.decode("utf-8", errors="replace").rstrip("\r")
                self.lines.append(None if self.too_long else text)
            self.partial, self.too_long = bytearray(), False


class ShellService(Service):
    message_ids = frozenset({_M.MAVLINK_MSG_ID_SERIAL_CONTROL})

    def __init__(
        self,
        api: System,
        reboot: Callable[[], CommandResult],
        gimbal_attitude: Callable[[], tuple[float, float]] | None = None,
    ) -> None:
        super().__init__()
        self.api = api
        self._reboot = reboot
        self._gimbal = gimbal_attitude
        self._consoles: dict[tuple[int, tuple[str, int]], _Console] = {}
        self.table = ParamTable(api)

    def handle(self, m: MAVLinkMessage, origin: Origin, now: int) -> list[Out]:
        if m.device != _M.SERIAL_CONTROL_DEV_SHELL or m.flags & _M.SERIAL_CONTROL_FLAG_REPLY:
            return []
        key = (origin.link, origin.addr)
        console = self._consoles.pop(key, None)  # popped and put back: the dict is in order of use
        if console is None:
            console = _Console(origin)
            if len(self._consoles) >= CLIENTS_MAX:
                del self._consoles[next(iter(self._consoles))]
        self._consoles[key] = console
        console.origin = origin
        n = max(0, min(int(m.count), len(m.data)))
        console.feed(bytes(m.data[:n]))
        out = ""
        if not console.started:
            console.started = True
            out += BANNER
            if not console.lines:
                out += PROMPT
        return self._reply(out + self._run_lines(console), origin)

    @property
    def busy(self) -> bool:
        return any(c.lines for c in self._consoles.values())

    def tick(self, state: VehicleState, now: int) -> list[Out]:
        """Lines that waited (more than ``LINES_PER_LOOP`` came in one message)."""
        outs: list[Out] = []
        for console in self._consoles.values():
            if console.lines:
                outs += self._reply(self._run_lines(console), console.origin)
        return outs

    def _run_lines(self, console: _Console) -> str:
        out = ""
        for _ in range(min(LINES_PER_LOOP, len(console.lines))):
            line = console.lines.popleft()
            result = "nsh: line too long\n" if line is None else self.run(line)
            out += (line or "") + "\n" + result + PROMPT
        return out

    def _reply(self, text: str, origin: Origin) -> list[Out]:
        assert self.mav is not None
        data = text.encode("utf-8")
        outs = []
        for i in range(0, len(data), CHUNK):
            part = data[i : i + CHUNK]
            msg = self.mav.serial_control_encode(
                _M.SERIAL_CONTROL_DEV_SHELL,
                _M.SERIAL_CONTROL_FLAG_REPLY,
                0,
                0,
                len(part),
                list(part.ljust(CHUNK, b"\0")),
            )
            outs.append(Out(msg, origin))
        return outs

    # ------------------------------------------------------------------ commands
    def run(self, line: str) -> str:
        """One command line's output (ends with a newline unless empty)."""
        try:
            argv = shlex.split(line)
        except ValueError as e:
            return f"nsh: {e}\n"
        if not argv:
            return ""
        cmd, args = argv[0], argv[1:]
        handler = {
            "help": self._help,
            "ver": self._ver,
            "param": self._param,
            "commander": self._commander,
            "listener": self._listener,
            "reboot": self._reboot_cmd,
        }.get(cmd)
        if handler is None:
            return f"nsh: {cmd}: command not found\n"
        return handler(args)

    def _help(self, _args: list[str]) -> str:
        return "Builtin Apps:\n  commander\n  help\n  listener\n  param\n  reboot\n  ver\n"

    def _ver(self, args: list[str]) -> str:
        hw = "HW arch: UAV_HARNESS_SITL\n"
        git = f"FW git tag: v{VERSION}\n"
        if args[:1] == ["hw"]:
            return hw
        if args[:1] == ["git"]:
            return git
        if args[:1] != ["all"]:
            return "usage: ver {all|hw|git}\n"
        return (
            hw
            + "HW type: SITL\n"
            + f"FW version: {VERSION} {FLIGHT_SW_VERSION & 0xFF} ({FLIGHT_SW_VERSION})\n"
            + git
            + "OS: Linux\n"  # what PX4 SITL's ``ver all`` says on Linux; never the host's kernel or Python
            + "OS version: Release 0.0.0 (0)\n"
            + "Toolchain: uav-harness\n"
        )

    def _param(self, args: list[str]) -> str:
        t = self.table
        if not args:
            return "usage: param {show [PATTERN]|set NAME VALUE|get NAME|save|load}\n"
        sub = args[0]
        if sub == "show":
            pattern = args[1] if len(args) > 1 else "*"
            lines = ["Symbols: x = used, + = saved, * = unsaved"]
            for i, d in enumerate(t.defs):
                if fnmatch.fnmatchcase(d.name, pattern):
                    v = self.api.params.get(d.name)
                    value = f"{int(v)}" if d.type == ParamType.INT32 else f"{float(v):.4f}"
                    used = "x" if d.flown else " "
                    saved = "+" if v != d.default else " "
                    lines.append(f"{used} {saved} {d.name} [{i},{i}] : {value}")
            lines.append(f"\n {len(t.defs)} parameters total.")
            return "\n".join(lines) + "\n"
        if sub in ("set", "get") and len(args) >= 2:
            name = args[1]
            index = t.index(name)
            if index < 0:
                return f"ERROR: Parameter {name} not found.\n"
            d = t.defs[index]
            old = self.api.params.get(name)
            if sub == "get":
                return f"{int(old)}\n" if d.type == ParamType.INT32 else f"{float(old):.4f}\n"
            if len(args) < 3:
                return "usage: param set NAME VALUE\n"
            try:
                number = float(args[2])
            except ValueError:
                return f"ERROR: {args[2]!r} is not a number\n"
            r = self.api.params.set(name, number)
            if not r.ok:
                return f"ERROR: {r.reason}\n"
            new = self.api.params.get(name)
            if d.type == ParamType.INT32:
                return f"{name}: curr: {int(old)} -> new: {int(new)}\n"
            return f"{name}: curr: {float(old):.4f} -> new: {float(new):.4f}\n"
        if sub == "save":
            return ""  # every change is saved when it is made (param_store.py)
        if sub == "load":
            return "use reboot: parameters are read from the saved file when the flight stack starts\n"
        return f"param: unknown command {sub!r}\n"

    def _commander(self, args: list[str]) -> str:
        api = self.api
        if not args:
            return "usage: commander {arm|disarm|takeoff|land|mode MODE|status}\n"
        sub, force = args[0], "-f" in args[1:]
        r: CommandResult
        if sub == "arm":
            r = api.action.arm(force)
        elif sub == "disarm":
            r = api.action.disarm(force)
        elif sub == "takeoff":
            r = api.action.takeoff(None)
        elif sub == "land":
            r = api.action.land()
        elif sub == "mode" and len(args) >= 2:
            mode = _MODES.get(args[1])
            if mode is None:
                return f"Unknown mode: {args[1]} (one of {', '.join(_MODES)})\n"
            r = api.action.set_mode(mode)
        elif sub == "status":
            s = api.telemetry.state()
            return f"armed: {s.armed}\nmode: {s.mode.name}\nlanded: {not s.in_air}\nfailsafe: {s.failsafe or 'none'}\n"
        else:
            return f"commander: unknown command {sub!r}\n"
        return "" if r.ok else f"ERROR: {r.reason}\n"

    def _reboot_cmd(self, _args: list[str]) -> str:
        r = self._reboot()
        return "Rebooting...\n" if r.ok else f"ERROR: {r.reason}\n"

    def _listener(self, args: list[str]) -> str:
        if not args:
            return "usage: listener TOPIC [-n COUNT]\n"
        topic = args[0]
        if topic not in TOPICS:
            return f"never published: {topic}\n(known here: {', '.join(TOPICS)})\n"
        n = 1
        if "-n" in args:
            try:
                n = max(1, min(10, int(args[args.index("-n") + 1])))
            except (IndexError, ValueError):
                return "usage: listener TOPIC [-n COUNT]\n"
        s = self.api.telemetry.state()
        body = self._topic(topic, s)
        us = max(s.t_ns, 0) // 1000
        one = f"\nTOPIC: {topic}\n {topic}\n    timestamp: {us} (0.000000 seconds ago)\n" + body
        return one * n

    def _topic(self, topic: str, s: VehicleState) -> str:
        f = "    {}: {}\n".format
        if topic == "vehicle_status":
            return (
                f("arming_state", 2 if s.armed else 1)
                + f("nav_state_name", s.mode.name)
                + f("failsafe", s.failsafe or "none")
            )
        if topic == "vehicle_attitude":
            return f("q", _vec(s.quat))
        if topic == "vehicle_local_position":
            return (
                f("x", f"{s.pos_ned_m[0]:.4f}")
                + f("y", f"{s.pos_ned_m[1]:.4f}")
                + f("z", f"{s.pos_ned_m[2]:.4f}")
                + f("vx", f"{s.vel_ned_m_s[0]:.4f}")
                + f("vy", f"{s.vel_ned_m_s[1]:.4f}")
                + f("vz", f"{s.vel_ned_m_s[2]:.4f}")
            )
        if topic == "vehicle_global_position":
            return f("lat", f"{s.lat_deg:.7f}") + f("lon", f"{s.lon_deg:.7f}") + f("alt", f"{s.alt_amsl_m:.3f}")
        if topic == "battery_status":
            b = s.battery
            return f("voltage_v", f"{b.voltage_v:.3f}") + f("remaining", f"{b.remaining:.3f}")
        if topic == "sensor_combined":
            return f("gyro_rad", _vec(s.rates_body_rad_s)) + f("accelerometer_m_s2", _vec(s.accel_body_m_s2))
        if topic == "vehicle_gps_position":
            g = s.gps
            return f("fix_type", g.fix_type) + f("satellites_used", g.satellites)
        if topic == "home_position":
            h = s.home
            if h is None:
                return f("valid_hpos", "False")
            return f("lat", f"{h.lat_deg:.7f}") + f("lon", f"{h.lon_deg:.7f}") + f("alt", f"{h.alt_amsl_m:.3f}")
        pitch, yaw = self._gimbal() if self._gimbal is not None else (math.nan, math.nan)
        return f("pitch_deg", f"{pitch:.2f}") + f("yaw_deg", f"{yaw:.2f}")
