"""What one PX4 service is to the registry (``px4_services.py``): a sans-I/O object that takes decoded
messages, commands and the passing of time, and returns ``Out`` items for the server to send.

- ``message_ids``: the messages it handles (``handle(msg, origin, now) -> outs``);
- ``commands()``: the COMMAND_LONG / COMMAND_INT ids it executes (the command service ACKs them as every other);
- ``tick(state, now)``: what falls due (sim time is ``state.t_ns``; ``now`` is the server's wall clock);
- ``busy``: work under way that the next ticks go on with (a long CRC32, queued shell lines);
- ``builders`` / ``stream_defaults``: messages it can build on request or stream.

``now`` is wall-clock nanoseconds (the server's clock); anything that models the vehicle runs on sim time.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import CommandResult, Severity, VehicleState
from harness.autopilot.mavlink.commands import CommandIn, CommandOutcome
from harness.autopilot.mavlink.messages import MAVLinkMessage, Origin, Out, statustext
from harness.autopilot.mavlink.telemetry import Builder

CommandHandler = Callable[[CommandIn], CommandOutcome]


class Service:
    """Defaults for every hook: handles nothing, builds nothing, nothing due."""

    message_ids: frozenset[int] = frozenset()
    builders: Mapping[int, Builder] = {}
    stream_defaults: Mapping[int, int] = {}

    def __init__(self) -> None:
        self.mav: mavlink2.MAVLink | None = None

    def bind(self, mav: mavlink2.MAVLink) -> None:
        """The server's encoder (called once, before any message or tick)."""
        self.mav = mav

    def handle(self, m: MAVLinkMessage, origin: Origin, now: int) -> list[Out]:
        return []

    def commands(self) -> Mapping[int, CommandHandler]:
        return {}

    def tick(self, state: VehicleState, now: int) -> list[Out]:
        return []

    @property
    def busy(self) -> bool:
        """Work is under way that ``tick`` goes on with (the server ticks again within milliseconds)."""
        return False

    def text(self, severity: Severity, text: str) -> Out:
        """One STATUSTEXT (at most 50 bytes) to everyone, sent as is (no repeat suppression)."""
        assert self.mav is not None
        return Out(statustext(self.mav, severity, text[:50], 0)[0])


def outcome(result: CommandResult, followups: list[MAVLinkMessage] | None = None) -> CommandOutcome:
    return CommandOutcome(result, followups or [])
