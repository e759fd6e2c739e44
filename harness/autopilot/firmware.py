"""Which flight stack a vehicle presents over MAVLink (its personality; ``mavlink/personality.py``).

A module of its own, free of heavy imports, so scenario files and the command line can name firmwares.
"""

from __future__ import annotations

import enum

from harness.core.errors import ScenarioError


class Firmware(enum.Enum):
    PX4 = "px4"
    ARDUPILOT = "ardupilot"

    @classmethod
    def parse(cls, text: object, where: str = "firmware") -> Firmware:
        """``'px4'`` / ``'ardupilot'`` (any case); a ScenarioError naming the choices otherwise."""
        try:
            return cls(str(text).strip().lower())
        except ValueError:
            choices = ", ".join(f.value for f in cls)
            raise ScenarioError(f"{where}: unknown firmware {text!r} (choose one of: {choices})") from None


def firmware_of(firmwares: tuple[Firmware, ...], vehicle: int) -> Firmware:
    """Vehicle ``vehicle``'s firmware: one entry for all, one per vehicle, or PX4 when none is given."""
    if not firmwares:
        return Firmware.PX4
    if len(firmwares) == 1:
        return firmwares[0]
    return firmwares[vehicle] if vehicle < len(firmwares) else Firmware.PX4
