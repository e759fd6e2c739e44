"""The autopilot as ArduCopter presents it to the generic MAVLink services.

- Missions: ArduPilot's item 0 is home. A download answers home as item 0 and the core's items from 1; an
  upload drops item 0 (the vehicle keeps its own home, as ArduCopter does when armed) and numbers the rest
  from 0 for the core; current item, MISSION_SET_CURRENT and MISSION_ITEM_REACHED are shifted by one.
- Parameters: ArduCopter names (:class:`~harness.autopilot.mavlink.ardupilot.params.CopterParams`).
- Status texts: the core's arming refusals become ArduPilot's ``PreArm: ...``, reached items
  ``Reached command #N``.

Everything else goes to the core unchanged.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

from harness.autopilot.api import (
    AttitudeTarget,
    AutopilotApi,
    CommandResult,
    FlightMode,
    GeoPoint,
    MavCmd,
    MavFrame,
    MissionItem,
    MissionKind,
    MissionReached,
    OffboardSetpoint,
    StatusText,
    VehicleState,
)
from harness.autopilot.mavlink.ardupilot.params import CopterParams

_ARMING_DENIED = "Arming denied: "


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
    return text if t == text.text else dataclasses.replace(text, text=t)


class CopterApi:
    """An ``AutopilotApi`` over the core with ArduCopter's mission numbering, parameters and texts."""

    def __init__(self, core: AutopilotApi, params: CopterParams) -> None:
        self.core = core
        self.vehicle = core.vehicle
        self.params = params
        self._last_in: VehicleState | None = None
        self._last_out: VehicleState | None = None

    def __getattr__(self, name: str) -> object:
        """Optional hooks of the core (``attach_bell``, ``ring_at``, ``inject_failure``, ``set_yaw`` ...)."""
        if name == "core":
            raise AttributeError(name)
        return getattr(self.core, name)

    # ------------------------------------------------------------------ state
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

    # ------------------------------------------------------------------ missions
    def upload_mission(self, items: Sequence[MissionItem], kind: MissionKind = MissionKind.MISSION) -> CommandResult:
        if kind != MissionKind.MISSION:
            return self.core.upload_mission(items, kind)
        rest = [it for it in items if it.seq != 0]
        return self.core.upload_mission([dataclasses.replace(it, seq=it.seq - 1) for it in rest], kind)

    def download_mission(self, kind: MissionKind = MissionKind.MISSION) -> tuple[MissionItem, ...]:
        items = self.core.download_mission(kind)
        if kind != MissionKind.MISSION:
            return items
        home = home_item(self.core.state().home)
        return (home, *(dataclasses.replace(it, seq=it.seq + 1) for it in items))

    def clear_mission(self, kind: MissionKind = MissionKind.MISSION) -> CommandResult:
        return self.core.clear_mission(kind)

    def set_current_item(self, seq: int) -> CommandResult:
        if seq == 0:  # ArduPilot: restart the mission (home is never flown to as an item)
            return self.core.set_current_item(0)
        return self.core.set_current_item(seq - 1)

    def start_mission(self) -> CommandResult:
        return self.core.start_mission()

    def pause_mission(self) -> CommandResult:
        return self.core.pause_mission()

    # ------------------------------------------------------------------ parameters
    def get_param(self, name: str) -> float | int:
        return self.params.get(name)

    def set_param(self, name: str, value: float) -> CommandResult:
        return self.params.set(name, value)

    # ------------------------------------------------------------------ the rest: the core's
    def arm(self, force: bool = False) -> CommandResult:
        return self.core.arm(force)

    def disarm(self, force: bool = False) -> CommandResult:
        return self.core.disarm(force)

    def set_mode(self, mode: FlightMode) -> CommandResult:
        return self.core.set_mode(mode)

    def takeoff(self, alt_m: float | None = None) -> CommandResult:
        return self.core.takeoff(alt_m)

    def land(self) -> CommandResult:
        return self.core.land()

    def return_to_launch(self) -> CommandResult:
        return self.core.return_to_launch()

    def hold(self) -> CommandResult:
        return self.core.hold()

    def set_offboard_setpoint(self, sp: OffboardSetpoint) -> CommandResult:
        return self.core.set_offboard_setpoint(sp)

    def set_attitude_target(self, target: AttitudeTarget) -> CommandResult:
        return self.core.set_attitude_target(target)

    def reposition(
        self, lat_deg: float | None, lon_deg: float | None, alt_amsl_m: float | None, yaw_rad: float | None = None
    ) -> CommandResult:
        return self.core.reposition(lat_deg, lon_deg, alt_amsl_m, yaw_rad)

    def orbit(
        self,
        radius_m: float,
        velocity_m_s: float,
        center_lat_deg: float | None = None,
        center_lon_deg: float | None = None,
        alt_amsl_m: float | None = None,
    ) -> CommandResult:
        return self.core.orbit(radius_m, velocity_m_s, center_lat_deg, center_lon_deg, alt_amsl_m)

    def change_speed(self, speed_m_s: float) -> CommandResult:
        return self.core.change_speed(speed_m_s)

    def set_home(self, point: GeoPoint | None = None) -> CommandResult:
        return self.core.set_home(point)

    def set_yaw(self, yaw_rad: float | None) -> CommandResult:
        fn: Callable[[float | None], CommandResult] | None = getattr(self.core, "set_yaw", None)
        if fn is None:
            return CommandResult.unsupported("this autopilot cannot point its nose on command")
        return fn(yaw_rad)
