"""The autopilot's services as ArduCopter presents them to the generic MAVLink services (``CopterSystem``).

- Missions: ArduPilot's item 0 is home. A download answers home as item 0 and the core's items from 1; an
  upload drops item 0 (the vehicle keeps its own home, as ArduCopter does when armed) and numbers the rest
  from 0 for the core; current item, MISSION_SET_CURRENT and MISSION_ITEM_REACHED are shifted by one.
- Parameters: ArduCopter names (:class:`~harness.autopilot.mavlink.ardupilot.params.CopterParams`).
- Status texts: the core's arming refusals become ArduPilot's ``PreArm: ...``, reached items
  ``Reached command #N``, the navigation-loss failsafe ``EKF variance``.

Every other service is the core's own object (no forwarding).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

from harness.autopilot.api import (
    CommandResult,
    GeoPoint,
    MavCmd,
    MavFrame,
    MissionItem,
    MissionKind,
    MissionReached,
    StatusText,
    VehicleState,
)
from harness.autopilot.camera import CameraDevice
from harness.autopilot.mavlink.ardupilot.params import CopterParams
from harness.autopilot.services import (
    Action,
    Bell,
    Failure,
    FollowMe,
    Gimbal,
    Gripper,
    LogFiles,
    ManualInput,
    Offboard,
    System,
)

_ARMING_DENIED = "Arming denied: "
_NAV_LOSS = "Failsafe: no position estimate"


def home_item(home: GeoPoint | None) -> MissionItem:
    """ArduPilot's mission item 0 (zeros until home is known, which DroneKit ignores)."""
    if home is None:
        return MissionItem(0, MavFrame.GLOBAL, MavCmd.NAV_WAYPOINT, x=0, y=0, z=0.0)
    return MissionItem(
        0,
        MavFrame.GLOBAL,
        MavCmd.NAV_WAYPOINT,
        x=round(home.lat_deg * 1e7),
        y=round(home.lon_deg * 1e7),
        z=home.alt_amsl_m,
    )


def copter_text(text: StatusText) -> StatusText:
    t = text.text
    if t.startswith(_ARMING_DENIED):
        t = "PreArm: " + t[len(_ARMING_DENIED) :]
    elif t.startswith("Mission item ") and t.endswith(" reached"):
        seq = t[len("Mission item ") : -len(" reached")]
        if seq.isdigit():
            t = f"Reached command #{int(seq) + 1}"
    elif t.startswith(_NAV_LOSS):
        t = "EKF variance"  # ArduCopter's ekf_check, before its EKF failsafe (FS_EKF_ACTION 1: LAND)
    return text if t == text.text else dataclasses.replace(text, text=t)


class CopterMission:
    """The core's ``mission`` service with ArduPilot's numbering (item 0 = home)."""

    def __init__(self, core: System) -> None:
        self.core = core.mission
        self.telemetry = core.telemetry

    def upload(self, items: Sequence[MissionItem], kind: MissionKind = MissionKind.MISSION) -> CommandResult:
        if kind != MissionKind.MISSION:
            return self.core.upload(items, kind)
        rest = [it for it in items if it.seq != 0]
        return self.core.upload([dataclasses.replace(it, seq=it.seq - 1) for it in rest], kind)

    def download(self, kind: MissionKind = MissionKind.MISSION) -> tuple[MissionItem, ...]:
        items = self.core.download(kind)
        if kind != MissionKind.MISSION:
            return items
        home = home_item(self.telemetry.state().home)
        return (home, *(dataclasses.replace(it, seq=it.seq + 1) for it in items))

    def clear(self, kind: MissionKind = MissionKind.MISSION) -> CommandResult:
        return self.core.clear(kind)

    def set_current(self, seq: int) -> CommandResult:
        if seq == 0:  # ArduPilot: restart the mission (home is never flown to as an item)
            return self.core.set_current(0)
        return self.core.set_current(seq - 1)

    def start(self) -> CommandResult:
        return self.core.start()

    def pause(self) -> CommandResult:
        return self.core.pause()


class CopterTelemetry:
    """The core's ``telemetry`` with ArduPilot's mission numbering and status texts."""

    def __init__(self, core: System) -> None:
        self.core = core.telemetry
        self._last_in: VehicleState | None = None
        self._last_out: VehicleState | None = None

    def state(self) -> VehicleState:
        s = self.core.state()
        if s is self._last_in and self._last_out is not None:
            return self._last_out
        m = s.mission
        out = s
        if m.count > 0:
            out = dataclasses.replace(
                s,
                mission=dataclasses.replace(
                    m, current_seq=m.current_seq + 1, count=m.count + 1, reached=tuple(r + 1 for r in m.reached)
                ),
            )
        self._last_in, self._last_out = s, out
        return out

    def pop_status_texts(self) -> list[StatusText]:
        return [copter_text(t) for t in self.core.pop_status_texts()]

    def pop_mission_reached(self) -> list[MissionReached]:
        return [dataclasses.replace(r, seq=r.seq + 1) for r in self.core.pop_mission_reached()]

    def arming_check(self) -> str:
        return self.core.arming_check()


class CopterSystem:
    """The core's services as ArduCopter presents them: its own ``mission``, ``telemetry`` and ``params``, no
    ``gimbal`` (this dialect has no mount); every other service is the core's own object."""

    def __init__(self, core: System, params: CopterParams) -> None:
        self.vehicle = core.vehicle
        self.params = params
        self.mission = CopterMission(core)
        self.telemetry = CopterTelemetry(core)
        self.action: Action = core.action
        self.offboard: Offboard = core.offboard
        self.failure: Failure | None = core.failure
        self.manual_control: ManualInput | None = core.manual_control
        self.follow_me: FollowMe | None = core.follow_me
        self.gripper: Gripper | None = core.gripper
        self.gimbal: Gimbal | None = None
        self.camera: CameraDevice | None = None  # ArduPilot SITL's camera is not presented (PX4's is)
        self.log_files: LogFiles | None = core.log_files
        self.bell: Bell | None = core.bell
