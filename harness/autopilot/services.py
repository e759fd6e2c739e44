"""The autopilot as MAVSDK's ``System`` sees a vehicle: one object per service, each behind a narrow protocol.

    system.action      arm, disarm, modes, takeoff, land, return, hold, reposition, orbit, speed, home, yaw
    system.mission     mission / fence / rally plans: upload, download, clear, current item, start, pause
    system.offboard    position / velocity / acceleration setpoints and attitude targets
    system.params      the parameter registry (``Params``: names, types, get, set)
    system.telemetry   the state snapshot, status texts, mission items reached, the arming check
    system.failure     failure injection (MAV_CMD_INJECT_FAILURE)       } optional: None when
    system.manual_control   MANUAL_CONTROL sticks                       } the autopilot has
    system.follow_me   FOLLOW_TARGET positions                          } no such capability,
    system.gripper     payload grippers (MAV_CMD_DO_GRIPPER)            } never probed for
    system.gimbal      a 2-axis camera gimbal (gimbal manager v2)       }
    system.log_files   the flight logs offered over MAVLink             }
    system.camera      a survey camera (MAVLink camera protocol v2)     }
    system.bell        the stepping thread's call to the MAVLink side   }

``harness.autopilot.autopilot.Autopilot`` composes them over one flight core; a firmware dialect
(``harness.autopilot.mavlink.ardupilot.adapter.CopterSystem``) composes the same services, replacing only
those whose MAVLink meaning differs (mission numbering, parameter names, status texts). Every method may be
called from any thread (the MAVLink side runs on the wall clock while ``step()`` runs in lockstep); commands
are validated at once and return a ``CommandResult``, their effect applies at the next step.

A new service is one protocol here, one member of :class:`System`, one object in ``Autopilot.__init__``
and, if MAVLink reaches it, one handler in ``harness.autopilot.mavlink``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Protocol

from harness.autopilot.api import (
    AttitudeTarget,
    CommandResult,
    FlightMode,
    GeoPoint,
    GimbalAttitude,
    MissionItem,
    MissionKind,
    MissionReached,
    OffboardSetpoint,
    StatusText,
    VehicleState,
)
from harness.autopilot.camera import CameraDevice
from harness.autopilot.params import Params


class Action(Protocol):
    """Commands that change what the vehicle does (MAVSDK ``action``)."""

    def arm(self, force: bool = False) -> CommandResult: ...
    def disarm(self, force: bool = False) -> CommandResult: ...
    def set_mode(self, mode: FlightMode) -> CommandResult: ...
    def takeoff(self, alt_m: float | None = None) -> CommandResult: ...
    def land(self) -> CommandResult: ...
    def return_to_launch(self) -> CommandResult: ...
    def hold(self) -> CommandResult: ...
    def reposition(
        self, lat_deg: float | None, lon_deg: float | None, alt_amsl_m: float | None, yaw_rad: float | None = None
    ) -> CommandResult: ...
    def orbit(
        self,
        radius_m: float,
        velocity_m_s: float,
        center_lat_deg: float | None = None,
        center_lon_deg: float | None = None,
        alt_amsl_m: float | None = None,
    ) -> CommandResult: ...
    def change_speed(self, speed_m_s: float) -> CommandResult: ...
    def set_home(self, point: GeoPoint | None = None) -> CommandResult: ...
    def set_yaw(self, yaw_rad: float | None) -> CommandResult: ...
    def reboot(self) -> CommandResult:
        """Restart the flight stack in place, as a SITL reboot does (disarmed only)."""
        ...


class Mission(Protocol):
    """Mission, fence and rally plans (MAVSDK ``mission`` / ``geofence`` / ``mission_raw``)."""

    def upload(self, items: Sequence[MissionItem], kind: MissionKind = MissionKind.MISSION) -> CommandResult: ...
    def download(self, kind: MissionKind = MissionKind.MISSION) -> tuple[MissionItem, ...]: ...
    def clear(self, kind: MissionKind = MissionKind.MISSION) -> CommandResult: ...
    def set_current(self, seq: int) -> CommandResult: ...
    def start(self) -> CommandResult: ...
    def pause(self) -> CommandResult: ...


class Offboard(Protocol):
    """Setpoints streamed by a companion or a script (MAVSDK ``offboard``)."""

    def set_setpoint(self, sp: OffboardSetpoint) -> CommandResult: ...
    def set_axes(self, sp: OffboardSetpoint) -> CommandResult:
        """A setpoint whose NaN components leave their axis to the others (ArduCopter's attitude targets)."""
        ...

    def set_attitude(self, target: AttitudeTarget) -> CommandResult: ...


class Telemetry(Protocol):
    """What the vehicle reports (MAVSDK ``telemetry``): a frozen snapshot of the last step, and its events."""

    def state(self) -> VehicleState: ...
    def pop_status_texts(self) -> list[StatusText]: ...
    def pop_mission_reached(self) -> list[MissionReached]: ...
    def arming_check(self) -> str:
        """'' when the vehicle may arm, else the first reason it may not."""
        ...


class Failure(Protocol):
    """MAV_CMD_INJECT_FAILURE (MAVSDK ``failure``)."""

    def inject(self, unit: int, kind: int, instance: int) -> CommandResult: ...


class ManualInput(Protocol):
    """MANUAL_CONTROL sticks (MAVSDK ``manual_control``): raw −1000…1000 axes."""

    def set_sticks(self, x: int, y: int, z: int, r: int) -> CommandResult: ...


class FollowMe(Protocol):
    """FOLLOW_TARGET positions of the target to follow (MAVSDK ``follow_me``)."""

    def set_target(
        self, lat_deg: float, lon_deg: float, alt_amsl_m: float, vel_ned_m_s: tuple[float, float, float]
    ) -> CommandResult: ...


class Gripper(Protocol):
    """Payload grippers (MAVSDK ``gripper``): MAV_CMD_DO_GRIPPER, instances 1…6."""

    def grab(self, instance: int = 1) -> CommandResult: ...
    def release(self, instance: int = 1) -> CommandResult: ...


class Gimbal(Protocol):
    """A camera gimbal (MAVSDK ``gimbal``): pitch earth-stabilised, yaw relative to the vehicle's heading
    (from north with ``yaw_lock``); degrees and degrees per second."""

    def set_angles(self, pitch_deg: float, yaw_deg: float, yaw_lock: bool = False) -> CommandResult: ...
    def set_rates(self, pitch_rate_deg_s: float, yaw_rate_deg_s: float, yaw_lock: bool = False) -> CommandResult: ...
    def point_at(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> CommandResult: ...
    def attitude(self) -> GimbalAttitude: ...


class LogFiles(Protocol):
    """The flight logs offered over MAVLink (MAVSDK ``log_files``)."""

    def files(self) -> list[tuple[Path, int, int]]:
        """(path, size in bytes up to the last whole message, start time in Unix seconds) of each log."""
        ...


class Bell(Protocol):
    """How the stepping thread tells the MAVLink side that something is due (``Autopilot.step``)."""

    def attach(self, ring: Callable[[], None]) -> None: ...
    def ring_at(self, t_ns: int) -> None: ...


class System(Protocol):
    """One vehicle as its services (the MAVLink server and the tests see nothing else).

    Members are read-only properties so that a class may hold a narrower type (its own implementation) and
    a dialect may share the core's objects.
    """

    @property
    def vehicle(self) -> int: ...
    @property
    def action(self) -> Action: ...
    @property
    def mission(self) -> Mission: ...
    @property
    def offboard(self) -> Offboard: ...
    @property
    def params(self) -> Params: ...
    @property
    def telemetry(self) -> Telemetry: ...
    @property
    def failure(self) -> Failure | None: ...
    @property
    def manual_control(self) -> ManualInput | None: ...
    @property
    def follow_me(self) -> FollowMe | None: ...
    @property
    def gripper(self) -> Gripper | None: ...
    @property
    def gimbal(self) -> Gimbal | None: ...
    @property
    def log_files(self) -> LogFiles | None: ...
    @property
    def camera(self) -> CameraDevice | None:
        """A survey camera (``harness.autopilot.camera``; the MAVLink camera protocol speaks for it)."""
        ...

    @property
    def bell(self) -> Bell | None: ...
