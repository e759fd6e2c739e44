"""The mission runtime's one piece of process-wide state (:data:`INSTALLED`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from harness.core.endpoints import VehicleEndpoints

if TYPE_CHECKING:
    from harness.simclock.runtime import SimRuntime


class Installed:
    """The mission runtime's one piece of process-wide state: what is installed in this process.

    Patching replaces process-wide functions (``time.sleep``, ``socket.socket``), so what they run on is
    process-wide too; it lives here and nowhere else (:data:`INSTALLED`): ``patch.install`` sets ``runtime``,
    ``simsocket.install`` sets ``sockets``, ``endpoints`` and ``team``.
    """

    __slots__ = ("endpoints", "runtime", "sockets", "team")

    def __init__(self) -> None:
        self.runtime: SimRuntime | None = None
        """The runtime time and waits follow (``patch.install``)."""
        self.sockets: SimRuntime | None = None
        """The runtime the mission's sockets wait on and send radio packets through (``simsocket.install``)."""
        self.endpoints: VehicleEndpoints | None = None
        """The vehicle a script's MAVLink addresses are mapped to (``simsocket.install``)."""
        self.team: tuple[VehicleEndpoints, ...] = ()
        """A swarm mission's vehicles (``HARNESS_VEHICLES``): its MAVLink to their own ports is settled and its
        MAVSDK connections to them listen on announced ports, as a one-vehicle mission's (``simsocket.install``)."""


INSTALLED = Installed()


def current() -> SimRuntime | None:
    """The sim runtime of this process, if it runs under ``harness mission``."""
    return INSTALLED.runtime
