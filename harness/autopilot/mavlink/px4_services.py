"""PX4 SITL's services beyond the flight core, registered in one place: sensor calibration, the gimbal
manager (for the autopilot's ``gimbal``, when it has one), MAVFTP, the MAVLink shell and reboot (one sans-I/O module each; ``service.py`` is their shape).

:class:`Px4Services` is what the PX4 dialect (``personality.Px4Dialect``) adds to the generic services: it
routes the messages each service declares, registers their commands with the command service (same ACK,
retransmission and refusal rules as every command), merges their message builders and default streams, and
collects what falls due at each server tick. A service is one line in :func:`px4_services`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import VehicleState
from harness.autopilot.mavlink.calibration import CalibrationService
from harness.autopilot.mavlink.camera import CameraComponent
from harness.autopilot.mavlink.dialect_api import Component
from harness.autopilot.mavlink.ftp import FtpService
from harness.autopilot.mavlink.gimbal import CMD_CONFIGURE, GimbalService
from harness.autopilot.mavlink.messages import MAVLinkMessage, Origin, Out
from harness.autopilot.mavlink.payload import WinchComponent
from harness.autopilot.mavlink.reboot import RebootService
from harness.autopilot.mavlink.service import CommandHandler, Service
from harness.autopilot.mavlink.shell import ShellService
from harness.autopilot.mavlink.telemetry import Builder
from harness.autopilot.services import System

_COMMAND_IDS = (mavlink2.MAVLINK_MSG_ID_COMMAND_LONG, mavlink2.MAVLINK_MSG_ID_COMMAND_INT)


class Px4Services:
    def __init__(self, api: System, sysid: int) -> None:
        vehicle = api.vehicle  # (not sysid - 1: ids repeat every 244 vehicles in a bigger run)
        self.calibration = CalibrationService(api)
        self.gimbal = GimbalService(api, api.gimbal, sysid) if api.gimbal is not None else None
        self.ftp = FtpService(api, vehicle)
        self.reboot = RebootService(api, vehicle)
        self.camera = CameraComponent(api.camera, api.telemetry.state) if api.camera is not None else None
        self.winch = WinchComponent()
        self.components: dict[int, Component] = {c.compid: c for c in (self.camera, self.winch) if c is not None}
        """The vehicle's other components (the server frames what they send with their own ids)."""
        self.shell = ShellService(api, self.reboot.reboot, self.gimbal.attitude_deg if self.gimbal else None)
        self.services: tuple[Service, ...] = tuple(
            s for s in (self.calibration, self.gimbal, self.ftp, self.shell, self.reboot, self.camera) if s is not None
        )
        self._by_message: dict[int, Service] = {}
        self.builders: dict[int, Builder] = {}
        self.stream_defaults: dict[int, int] = {}
        self._commands: dict[int, CommandHandler] = {}
        for s in self.services:
            for mid in s.message_ids:
                self._by_message[mid] = s
            self.builders.update(s.builders)
            self.stream_defaults.update(s.stream_defaults)
            self._commands.update(s.commands())

    def bind(self, mav: mavlink2.MAVLink, set_interval: Callable[[int, float], bool]) -> None:
        """The server's encoder and its SET_MESSAGE_INTERVAL (streams a service starts when it is used)."""
        for s in self.services:
            s.bind(mav)
        if self.gimbal is not None:
            self.gimbal.bind_streams(set_interval)

    def command_handlers(self) -> Mapping[int, CommandHandler]:
        return self._commands

    def handle(self, m: MAVLinkMessage, origin: Origin, now: int) -> list[Out] | None:
        """The outs of the service that owns ``m``; None when none does (the generic services take it)."""
        mid = m.get_msgId()
        if mid in _COMMAND_IDS:
            if m.command == CMD_CONFIGURE and self.gimbal is not None:  # who takes gimbal control: the sender
                self.gimbal.sender = (origin.sysid, origin.compid)
            if self.camera is not None:
                self.camera.looked_for(m)
            return None
        service = self._by_message.get(mid)
        return None if service is None else service.handle(m, origin, now)

    def tick(self, state: VehicleState, now: int) -> list[Out]:
        outs: list[Out] = []
        for s in self.services:
            outs += s.tick(state, now)
        return outs

    @property
    def busy(self) -> bool:
        """Work under way over several ticks (a large file's CRC32, shell lines that waited); asked at every
        service of the server, so only the services that can be busy are asked."""
        return self.ftp.busy or self.shell.busy

    def close(self) -> None:
        self.ftp.close()
