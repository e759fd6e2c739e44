"""What a firmware dialect is to the MAVLink server, and what the server is to a dialect (the two sides of
``harness.autopilot.mavlink.personality.make_dialect``), apart from either implementation."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Protocol

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import Severity, VehicleState
from harness.autopilot.mavlink.commands import CommandIn, CommandOutcome
from harness.autopilot.mavlink.heartbeat import HeartbeatSchedule
from harness.autopilot.mavlink.messages import MAVLinkMessage, Origin, Out
from harness.autopilot.mavlink.telemetry import Builder, StreamScheduler
from harness.autopilot.params import Params
from harness.autopilot.services import System


class DialectHost(Protocol):
    """What a dialect may use of its server (the server thread calls the dialect, under the server lock)."""

    streams: StreamScheduler
    heartbeat: HeartbeatSchedule

    @property
    def mav(self) -> mavlink2.MAVLink:
        """The encoder (its ``*_encode`` methods build messages)."""
        ...

    def say(self, severity: Severity, text: str, now: int) -> None: ...
    def link_name(self, link: int) -> str: ...


class Component(Protocol):
    """A MAVLink component of the vehicle's system beside the autopilot: what is addressed to ``compid`` is its
    (``handle_component``); it sends as ``compid`` (``Out.compid``), with an encoder of its own."""

    compid: int

    def bind_component(self, mav: mavlink2.MAVLink) -> None: ...
    def heartbeat(self) -> MAVLinkMessage | None:
        """Its HEARTBEAT (sent with the autopilot's), or None for a component without one."""
        ...

    def handle_component(self, m: MAVLinkMessage, origin: Origin) -> list[Out]: ...


class Dialect(Protocol):
    api: System
    mission_float_form: bool
    param_bytewise: bool
    builders: Mapping[int, Builder]
    stream_defaults: Mapping[int, int]
    own_params: Params | None
    """The dialect's own parameter table, stored per vehicle beside the core's (ArduCopter's names), or None."""
    components: Mapping[int, Component]
    """The vehicle's other MAVLink components by id (PX4: the camera, 100; the winch, 169)."""

    def bind(self, host: DialectHost, mav: mavlink2.MAVLink, sysid: int) -> None: ...
    def check_mission_item(self, m: MAVLinkMessage) -> tuple[int, str]:
        """``(MAV_MISSION_RESULT, reason)`` the firmware answers to one uploaded item (``mission_items.py``)."""
        ...

    def heartbeat(self, mav: mavlink2.MAVLink, state: VehicleState) -> MAVLinkMessage: ...
    def autopilot_version(self, mav: mavlink2.MAVLink, sysid: int) -> MAVLinkMessage: ...
    def command_handlers(self) -> Mapping[int, Callable[[CommandIn], CommandOutcome]]: ...
    def handle(self, m: MAVLinkMessage, origin: Origin, now: int) -> list[Out] | None: ...
    def tick(self, state: VehicleState, now: int) -> list[Out]: ...
    @property
    def busy(self) -> bool:
        """Work under way that the next ticks go on with (the server ticks again within milliseconds)."""
        ...

    def close(self) -> None:
        """Release what the dialect holds open (MAVFTP's open files) when its vehicle stops; idempotent."""
        ...
