"""The autopilot's typed in-process API: modes, states, missions, commands and their results.

This module is the contract between the flight core (``harness.autopilot.autopilot.Autopilot``), its tests
and the MAVLink interface (``harness.autopilot.mavlink``). It holds only data types (the services that use
them are ``harness.autopilot.services``); it imports nothing heavy, so anything can depend on it.

Conventions: world frame NED (metres) with its origin at the scenario's world origin; body frame FRD;
quaternions (w, x, y, z) rotate body to world; angles in radians unless a name says ``_deg``; times are
integer nanoseconds of sim time (``t_ns``). Altitudes: ``alt_amsl_m`` above mean sea level,
``rel_alt_m`` above home.

Threading: every service method may be called from any thread (MAVLink runs on the wall clock
while ``step()`` runs in lockstep). Commands are validated at once and return a ``CommandResult``; their
effect applies at the next ``step()``.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

from harness.core.geo import Quat, Vec3


class MainMode(enum.IntEnum):
    """PX4 custom main mode (HEARTBEAT custom_mode bits 16-23)."""

    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7


class AutoSubMode(enum.IntEnum):
    """PX4 custom sub mode of AUTO (HEARTBEAT custom_mode bits 24-31)."""

    NONE = 0
    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6
    FOLLOW_TARGET = 8
    PRECLAND = 9


class FlightMode(enum.Enum):
    """The autopilot's flight modes. ``value`` is (main mode, sub mode) as PX4 encodes them.

    ``ORBIT`` is PX4's orbit (shown as POSCTL on HEARTBEAT, like PX4 does, plus a distinct internal mode).
    """

    MANUAL = (MainMode.MANUAL, AutoSubMode.NONE)
    STABILIZED = (MainMode.STABILIZED, AutoSubMode.NONE)
    ALTCTL = (MainMode.ALTCTL, AutoSubMode.NONE)
    POSCTL = (MainMode.POSCTL, AutoSubMode.NONE)
    OFFBOARD = (MainMode.OFFBOARD, AutoSubMode.NONE)
    TAKEOFF = (MainMode.AUTO, AutoSubMode.TAKEOFF)
    HOLD = (MainMode.AUTO, AutoSubMode.LOITER)
    MISSION = (MainMode.AUTO, AutoSubMode.MISSION)
    RTL = (MainMode.AUTO, AutoSubMode.RTL)
    LAND = (MainMode.AUTO, AutoSubMode.LAND)
    FOLLOW_TARGET = (MainMode.AUTO, AutoSubMode.FOLLOW_TARGET)
    ORBIT = (MainMode.POSCTL, AutoSubMode.NONE, "orbit")

    __hash__ = object.__hash__
    """Members are singletons compared by identity: hashed by identity too (C), not by name (a Python call
    in ``Enum``) — the flight core looks modes up in dicts and sets every tick."""

    @property
    def main_mode(self) -> MainMode:
        return self.value[0]

    @property
    def sub_mode(self) -> AutoSubMode:
        return self.value[1]

    @property
    def custom_mode(self) -> int:
        """HEARTBEAT ``custom_mode``: main << 16 | sub << 24."""
        return (int(self.value[0]) << 16) | (int(self.value[1]) << 24)

    @classmethod
    def from_px4(cls, main: int, sub: int = 0) -> FlightMode | None:
        """The mode PX4 means by (main, sub); ``None`` for modes this autopilot does not have.

        AUTO with sub 0 or READY means HOLD (PX4 goes to loiter); the ``ORBIT`` alias is never returned.
        """
        if main == MainMode.AUTO and sub in (AutoSubMode.NONE, AutoSubMode.READY):
            return cls.HOLD
        for mode in cls:
            if mode is cls.ORBIT:
                continue
            if int(mode.value[0]) == main and (main != MainMode.AUTO or int(mode.value[1]) == sub):
                return mode
        return None

    @classmethod
    def from_custom_mode(cls, custom_mode: int) -> FlightMode | None:
        return cls.from_px4((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)


class LandedState(enum.IntEnum):
    """MAVLink MAV_LANDED_STATE."""

    UNDEFINED = 0
    ON_GROUND = 1
    IN_AIR = 2
    TAKEOFF = 3
    LANDING = 4


ModeStatus = tuple[bool, int, int, int]
"""(armed, MAV_LANDED_STATE — ON_GROUND while disarmed —, PX4 main mode, sub mode): what rings the bell."""

TickStatus = tuple[bool, int, int, int, tuple[float, float] | None]
"""What the autopilot reports with each tick's motor commands (END-TICK-AC ``status``, for recording): the
:data:`ModeStatus`, then the gimbal's (pitch, yaw relative to the heading) in degrees, None while no gimbal was
used. A plain tuple: it is made for every vehicle on every tick."""


@dataclass(frozen=True, slots=True)
class GimbalAttitude:
    """A gimbal's attitude (``harness.autopilot.gimbal``): pitch earth-stabilised, yaw relative to the heading."""

    pitch_deg: float
    yaw_deg: float
    pitch_rate_deg_s: float
    yaw_rate_deg_s: float
    yaw_lock: bool
    """The yaw setpoint is held in the earth frame."""


class Failsafe(enum.StrEnum):
    """A failsafe the commander has taken (its value is what telemetry and tests see)."""

    NONE = ""
    BATTERY = "battery"
    BATTERY_CRITICAL = "battery_critical"
    OFFBOARD_LOSS = "offboard_loss"
    GEOFENCE = "geofence"
    RC_LOSS = "rc_loss"
    """Manual control lost (``harness.autopilot.manual``)."""
    NAVIGATION = "navigation"
    """No position estimate (GPS lost; ``harness.autopilot.failures``)."""


class MissionKind(enum.IntEnum):
    """MAVLink MAV_MISSION_TYPE."""

    MISSION = 0
    FENCE = 1
    RALLY = 2


class Result(enum.IntEnum):
    """MAVLink MAV_RESULT values for a command."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4
    IN_PROGRESS = 5


@dataclass(frozen=True, slots=True)
class CommandResult:
    result: Result
    reason: str = ""
    """Why it was refused (empty when accepted); the MAVLink side sends it as STATUSTEXT."""

    @property
    def ok(self) -> bool:
        return self.result == Result.ACCEPTED

    @classmethod
    def accepted(cls) -> CommandResult:
        return _ACCEPTED

    @classmethod
    def denied(cls, reason: str) -> CommandResult:
        return cls(Result.DENIED, reason)

    @classmethod
    def rejected(cls, reason: str) -> CommandResult:
        return cls(Result.TEMPORARILY_REJECTED, reason)

    @classmethod
    def unsupported(cls, reason: str) -> CommandResult:
        return cls(Result.UNSUPPORTED, reason)

    @classmethod
    def failed(cls, reason: str) -> CommandResult:
        return cls(Result.FAILED, reason)


_ACCEPTED = CommandResult(Result.ACCEPTED)


class MavFrame(enum.IntEnum):
    """The MAV_FRAME values mission items and setpoints use."""

    GLOBAL = 0
    LOCAL_NED = 1
    MISSION = 2
    GLOBAL_RELATIVE_ALT = 3
    LOCAL_ENU = 4
    GLOBAL_INT = 5
    GLOBAL_RELATIVE_ALT_INT = 6
    LOCAL_OFFSET_NED = 7
    BODY_NED = 8
    BODY_OFFSET_NED = 9
    GLOBAL_TERRAIN_ALT = 10
    GLOBAL_TERRAIN_ALT_INT = 11
    BODY_FRD = 12


class MavCmd(enum.IntEnum):
    """MAV_CMD values the mission executor and command handling know."""

    NAV_WAYPOINT = 16
    NAV_LOITER_UNLIM = 17
    NAV_LOITER_TURNS = 18
    NAV_LOITER_TIME = 19
    NAV_RETURN_TO_LAUNCH = 20
    NAV_LAND = 21
    NAV_TAKEOFF = 22
    DO_ORBIT = 34
    NAV_DELAY = 93
    DO_SET_MODE = 176
    DO_CHANGE_SPEED = 178
    DO_SET_HOME = 179
    DO_REPOSITION = 192
    DO_SET_ROI_LOCATION = 195
    DO_SET_ROI_NONE = 197
    DO_SET_CAM_TRIGG_DIST = 206
    DO_GRIPPER = 211
    MISSION_START = 300
    ARM_DISARM = 400
    DO_GIMBAL_MANAGER_PITCHYAW = 1000
    DO_GIMBAL_MANAGER_CONFIGURE = 1001
    IMAGE_START_CAPTURE = 2000
    IMAGE_STOP_CAPTURE = 2001
    VIDEO_START_CAPTURE = 2500
    VIDEO_STOP_CAPTURE = 2501
    NAV_FENCE_RETURN_POINT = 5000
    NAV_FENCE_POLYGON_VERTEX_INCLUSION = 5001
    NAV_FENCE_POLYGON_VERTEX_EXCLUSION = 5002
    NAV_FENCE_CIRCLE_INCLUSION = 5003
    NAV_FENCE_CIRCLE_EXCLUSION = 5004
    NAV_RALLY_POINT = 5100


SKIPPED_MISSION_COMMANDS = frozenset({178, 195, 197, 206, 1000, 1001, 2000, 2001, 2500, 2501})
"""Mission items accepted and stepped over at once (speed change is applied, then stepped over)."""
CAMERA_MISSION_COMMANDS = frozenset({206, 2000, 2001, 2500, 2501})
"""Of those, the camera's: handed to the autopilot's camera as they are passed (PX4 re-issues them)."""


@dataclass(frozen=True, slots=True)
class MissionItem:
    """One mission / fence / rally item, 1:1 with MAVLink MISSION_ITEM_INT.

    ``x``/``y`` are latitude/longitude: an ``int`` is degrees * 1e7 (the INT form), a ``float`` is degrees.
    For LOCAL frames they are metres north/east. ``z`` is the altitude in the item's frame (relative to home
    for GLOBAL_RELATIVE_ALT*, AMSL for GLOBAL*, metres up... as MAVLink defines).
    """

    seq: int
    frame: int
    command: int
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    x: int | float = 0
    y: int | float = 0
    z: float = 0.0
    autocontinue: bool = True
    current: bool = False
    mission_type: MissionKind = MissionKind.MISSION

    @property
    def lat_deg(self) -> float:
        return self.x * 1e-7 if isinstance(self.x, int) else float(self.x)

    @property
    def lon_deg(self) -> float:
        return self.y * 1e-7 if isinstance(self.y, int) else float(self.y)

    @property
    def is_global(self) -> bool:
        return self.frame not in (
            MavFrame.LOCAL_NED,
            MavFrame.LOCAL_ENU,
            MavFrame.LOCAL_OFFSET_NED,
            MavFrame.BODY_NED,
            MavFrame.BODY_OFFSET_NED,
            MavFrame.BODY_FRD,
            MavFrame.MISSION,
        )

    @property
    def is_relative_alt(self) -> bool:
        return self.frame in (MavFrame.GLOBAL_RELATIVE_ALT, MavFrame.GLOBAL_RELATIVE_ALT_INT)


class OffboardFrame(enum.IntEnum):
    LOCAL_NED = 1
    BODY_NED = 8
    """Velocity/acceleration rotated by the current heading (MAVSDK's 'body' velocity: forward, right, down)."""


@dataclass(frozen=True, slots=True)
class OffboardSetpoint:
    """A SET_POSITION_TARGET_LOCAL_NED as the flight core uses it; ``None`` fields are ignored (masked).

    In ``BODY_NED`` frame, position is an offset from the current position in the heading frame and
    velocity / acceleration are forward-right-down.
    """

    position_m: Vec3 | None = None
    velocity_m_s: Vec3 | None = None
    accel_m_s2: Vec3 | None = None
    yaw_rad: float | None = None
    yaw_rate_rad_s: float | None = None
    frame: OffboardFrame = OffboardFrame.LOCAL_NED


@dataclass(frozen=True, slots=True)
class AttitudeTarget:
    """A SET_ATTITUDE_TARGET: attitude quaternion and/or body rates, collective thrust in [0, 1]."""

    quat: Quat | None
    thrust: float
    body_rates_rad_s: Vec3 | None = None


@dataclass(frozen=True, slots=True)
class GeoPoint:
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float


@dataclass(frozen=True, slots=True)
class Health:
    gyro_ok: bool = False
    accel_ok: bool = False
    mag_ok: bool = False
    baro_ok: bool = False
    gps_ok: bool = False
    """The global position is usable: GPS checks passed for 10 s, the estimate converged (PX4 EKF2)."""
    gps_fix_ok: bool = False
    """A 3D fix with good accuracy now (home is set at the first one, before ``gps_ok``)."""
    local_position_ok: bool = False
    home_ok: bool = False
    preflight_ok: bool = False
    """Every arming check passes (MAVSDK's ``is_armable``)."""


@dataclass(frozen=True, slots=True)
class GpsInfo:
    fix_type: int = 0
    satellites: int = 0
    eph_m: float = 99.0
    epv_m: float = 99.0
    lat_deg: float = 0.0
    lon_deg: float = 0.0
    alt_amsl_m: float = 0.0
    vel_ned_m_s: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class BatteryState:
    voltage_v: float = 0.0
    current_a: float = 0.0
    remaining: float = 1.0
    """Fraction in [0, 1]."""
    consumed_mah: float = 0.0
    cells: int = 4


@dataclass(frozen=True, slots=True)
class MissionProgress:
    current_seq: int = 0
    count: int = 0
    reached: tuple[int, ...] = ()
    finished: bool = False
    active: bool = False
    """The MISSION mode is running it (not paused or in another mode)."""


@dataclass(frozen=True, slots=True)
class VehicleState:
    """A frozen snapshot of the autopilot, taken at the end of a ``step()`` (``t_ns`` of that tick)."""

    t_ns: int = 0
    vehicle: int = 0
    armed: bool = False
    mode: FlightMode = FlightMode.HOLD
    landed_state: LandedState = LandedState.ON_GROUND
    # Estimate (from sensors, unless use_ground_truth)
    pos_ned_m: Vec3 = (0.0, 0.0, 0.0)
    vel_ned_m_s: Vec3 = (0.0, 0.0, 0.0)
    lat_deg: float = 0.0
    lon_deg: float = 0.0
    alt_amsl_m: float = 0.0
    rel_alt_m: float = 0.0
    quat: Quat = (1.0, 0.0, 0.0, 0.0)
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    yaw_rad: float = 0.0
    rates_body_rad_s: Vec3 = (0.0, 0.0, 0.0)
    accel_body_m_s2: Vec3 = (0.0, 0.0, -9.81)
    mag_body_gauss: Vec3 | None = None
    """The last magnetometer sample the estimator used (None before the first)."""
    baro_pa: float | None = None
    """The last barometer pressure the estimator used (None before the first)."""
    home: GeoPoint | None = None
    home_ned_m: Vec3 | None = None
    battery: BatteryState = field(default_factory=BatteryState)
    gps: GpsInfo = field(default_factory=GpsInfo)
    health: Health = field(default_factory=Health)
    mission: MissionProgress = field(default_factory=MissionProgress)
    offboard_active: bool = False
    motors: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
    throttle: float = 0.0
    """Collective thrust command in [0, 1] (VFR_HUD throttle)."""
    max_speed_m_s: float = 0.0
    """Current horizontal speed limit (changed by DO_CHANGE_SPEED)."""
    failsafe: Failsafe = Failsafe.NONE
    """The active failsafe (``Failsafe.NONE``, '', when none)."""
    fence_max_hor_m: float = 0.0
    """The geofence's horizontal distance limit from home (0: none)."""
    grippers_grabbed: tuple[int, ...] = ()
    """The gripper instances (1…6) holding a payload (``harness.autopilot.gripper``)."""

    @property
    def in_air(self) -> bool:
        return self.landed_state in (LandedState.IN_AIR, LandedState.LANDING)

    @property
    def ground_speed_m_s(self) -> float:
        return math.hypot(self.vel_ned_m_s[0], self.vel_ned_m_s[1])


class Severity(enum.IntEnum):
    """MAVLink MAV_SEVERITY."""

    EMERGENCY = 0
    ALERT = 1
    CRITICAL = 2
    ERROR = 3
    WARNING = 4
    NOTICE = 5
    INFO = 6
    DEBUG = 7


@dataclass(frozen=True, slots=True)
class StatusText:
    t_ns: int
    severity: Severity
    text: str


@dataclass(frozen=True, slots=True)
class MissionReached:
    """A mission item was reached (MAVLink MISSION_ITEM_REACHED)."""

    t_ns: int
    seq: int
