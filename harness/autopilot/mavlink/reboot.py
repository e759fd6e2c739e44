"""MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN (246) as PX4 SITL answers it: param1 = 1 restarts the flight stack in
place — on the ground and disarmed only (DENIED otherwise) — with its parameters read again from the saved
file (defaults, the run's overrides, then ``<run dir>/params/vehicle-<i>.json``), a new estimator and no home
until the next good fix; the mission, fence and rally points stay (PX4 keeps them in dataman). ACCEPTED,
then the STATUSTEXT "Rebooted: flight stack restarted"; heartbeats never stop (the process does not restart:
``time_boot_ms`` keeps counting). param1 = 0 is accepted and does nothing; shutdown (2) and bootloader (3)
are UNSUPPORTED, as in SITL. The shell's ``reboot`` comes here too.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping

from harness.autopilot.api import CommandResult, Severity, VehicleState
from harness.autopilot.mavlink.commands import CommandIn, CommandOutcome
from harness.autopilot.mavlink.messages import Out
from harness.autopilot.mavlink.param_store import reload_params, run_dir_of
from harness.autopilot.mavlink.service import CommandHandler, Service, outcome
from harness.autopilot.services import System

log = logging.getLogger(__name__)

CMD_PREFLIGHT_REBOOT_SHUTDOWN = 246


class RebootService(Service):
    def __init__(self, api: System, vehicle: int) -> None:
        super().__init__()
        self.api = api
        self.vehicle = vehicle
        self.reboots = 0
        self._said: list[str] = []

    def commands(self) -> Mapping[int, CommandHandler]:
        return {CMD_PREFLIGHT_REBOOT_SHUTDOWN: self._command}

    def _command(self, c: CommandIn) -> CommandOutcome:
        action = c.params[0]
        if math.isnan(action) or action == 0:  # MAVSDK sends NaN for what it leaves unset
            return outcome(CommandResult.accepted())
        if math.isinf(action):
            return outcome(CommandResult.denied("reboot: param1 must be 0, 1, 2 or 3"))
        if action != 1:
            return outcome(CommandResult.unsupported("only a reboot of the autopilot (param1 = 1) is simulated"))
        return outcome(self.reboot())

    def reboot(self) -> CommandResult:
        if self.api.telemetry.state().armed:
            return CommandResult.denied("Reboot denied: disarm first")
        for reason in reload_params(self.api.params, run_dir_of(self.api), self.vehicle):
            log.warning("vehicle %d: reboot: saved parameter not restored: %s", self.vehicle, reason)
        result = self.api.action.reboot()
        if result.ok:
            self.reboots += 1
            self._said.append("Rebooted: flight stack restarted")
        return result

    def tick(self, state: VehicleState, now: int) -> list[Out]:
        said, self._said = self._said, []
        return [self.text(Severity.INFO, t) for t in said]
