"""Firmware personalities: what a vehicle's MAVLink side says it is, on one flight core.

The services of ``harness.autopilot.mavlink`` (commands, parameters, mission, telemetry) speak the PX4
dialect. A :class:`~harness.autopilot.mavlink.dialect_api.Dialect` is the thin layer of one firmware over them, made per vehicle by
:func:`make_dialect`:

- ``api``: the autopilot as the services see it (ArduCopter: mission seq 0 = home, ArduPilot parameter
  names, ArduPilot status texts);
- identity: ``heartbeat`` (autopilot type, custom mode numbers) and ``autopilot_version``;
- ``command_handlers``: commands whose meaning differs (DO_SET_MODE, NAV_TAKEOFF's altitude, ...);
- ``handle``: messages the firmware treats on its own (SET_MODE, GUIDED targets, REQUEST_DATA_STREAM);
  None lets the generic service have them;
- ``builders`` / ``stream_defaults``: extra telemetry and the default stream rates;
- ``tick``: periodic extras (ArduPilot's PreArm reports, the region of interest);
- ``mission_float_form`` / ``param_bytewise``: protocol conventions.

PX4 is the identity of the services themselves; :class:`Px4Dialect` adds PX4 SITL's own services
(calibration, gimbal, MAVFTP, shell, reboot: ``px4_services.py``). A third firmware is one module with a
``Dialect`` class and a line in ``_FACTORIES``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import VehicleState
from harness.autopilot.firmware import Firmware
from harness.autopilot.mavlink.commands import CommandIn, CommandOutcome
from harness.autopilot.mavlink.dialect_api import Component, Dialect, DialectHost
from harness.autopilot.mavlink.heartbeat import heartbeat_message
from harness.autopilot.mavlink.messages import MAVLinkMessage, Origin, Out
from harness.autopilot.mavlink.mission_items import px4_item_result
from harness.autopilot.mavlink.px4_services import Px4Services
from harness.autopilot.mavlink.telemetry import DEFAULT_INTERVALS_NS, Builder
from harness.autopilot.mavlink.version import autopilot_version
from harness.autopilot.params import Params
from harness.autopilot.services import System


class Px4Dialect:
    """PX4: the services as they are, plus PX4 SITL's own (``px4_services.py``)."""

    mission_float_form = False
    param_bytewise = True
    own_params: Params | None = None

    def __init__(self, api: System, sysid: int = 1) -> None:
        self.api = api
        self.px4 = Px4Services(api, sysid)
        self.components: Mapping[int, Component] = self.px4.components
        self.builders: Mapping[int, Builder] = self.px4.builders
        self.stream_defaults: Mapping[int, int] = {**DEFAULT_INTERVALS_NS, **self.px4.stream_defaults}

    def bind(self, host: DialectHost, mav: mavlink2.MAVLink, sysid: int) -> None:
        self.px4.bind(mav, host.streams.set_interval)

    def check_mission_item(self, m: MAVLinkMessage) -> tuple[int, str]:
        return px4_item_result(m)

    def heartbeat(self, mav: mavlink2.MAVLink, state: VehicleState) -> MAVLinkMessage:
        return heartbeat_message(mav, state)

    def autopilot_version(self, mav: mavlink2.MAVLink, sysid: int) -> MAVLinkMessage:
        return autopilot_version(mav, sysid)

    def command_handlers(self) -> Mapping[int, Callable[[CommandIn], CommandOutcome]]:
        return self.px4.command_handlers()

    def handle(self, m: MAVLinkMessage, origin: Origin, now: int) -> list[Out] | None:
        return self.px4.handle(m, origin, now)

    def tick(self, state: VehicleState, now: int) -> list[Out]:
        return self.px4.tick(state, now)

    @property
    def busy(self) -> bool:
        return self.px4.busy

    def close(self) -> None:
        self.px4.close()


def _ardupilot(api: System, sysid: int) -> Dialect:
    from harness.autopilot.mavlink.ardupilot.dialect import CopterDialect

    return CopterDialect(api, sysid)


_FACTORIES: dict[Firmware, Callable[[System, int], Dialect]] = {
    Firmware.PX4: Px4Dialect,
    Firmware.ARDUPILOT: _ardupilot,
}


def make_dialect(firmware: Firmware, api: System, sysid: int) -> Dialect:
    return _FACTORIES[firmware](api, sysid)


def core_param_defaults(firmware: Firmware) -> dict[str, float]:
    """Core parameter values a firmware's vehicles start with (before scenario overrides)."""
    if firmware is Firmware.ARDUPILOT:
        from harness.autopilot.mavlink.ardupilot.params import CORE_DEFAULTS

        return dict(CORE_DEFAULTS)
    return {}
