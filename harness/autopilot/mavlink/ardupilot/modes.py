"""ArduCopter flight modes: numbers, which core mode each one flies on, and the mode the HEARTBEAT shows.

ArduCopter's HEARTBEAT ``custom_mode`` is the mode number (``ArduCopter/mode.h``; pymavlink's
``mode_mapping_acm`` gives scripts the names). The flight core has fewer modes than ArduCopter shows:
GUIDED, LOITER and BRAKE all hold a position target (core ``HOLD``), GUIDED's takeoff and velocity
targets run on the core's ``TAKEOFF`` and ``OFFBOARD``. :class:`ModeTracker` remembers the ArduCopter mode
that was asked for and keeps showing it while the core stays in one of the modes it runs on; when the core
leaves them by itself (a failsafe return, the end of a landing) the shown mode follows the core.
"""

from __future__ import annotations

import enum

from harness.autopilot.api import FlightMode


class CopterMode(enum.IntEnum):
    """ArduCopter's mode numbers (``custom_mode``)."""

    STABILIZE = 0
    ACRO = 1
    ALT_HOLD = 2
    AUTO = 3
    GUIDED = 4
    LOITER = 5
    RTL = 6
    CIRCLE = 7
    LAND = 9
    DRIFT = 11
    SPORT = 13
    FLIP = 14
    AUTOTUNE = 15
    POSHOLD = 16
    BRAKE = 17
    THROW = 18
    AVOID_ADSB = 19
    GUIDED_NOGPS = 20
    SMART_RTL = 21
    FLOWHOLD = 22
    FOLLOW = 23
    ZIGZAG = 24
    SYSTEMID = 25
    AUTOROTATE = 26
    AUTO_RTL = 27


SUPPORTED: frozenset[CopterMode] = frozenset(
    {
        CopterMode.STABILIZE,
        CopterMode.ALT_HOLD,
        CopterMode.AUTO,
        CopterMode.GUIDED,
        CopterMode.LOITER,
        CopterMode.RTL,
        CopterMode.CIRCLE,
        CopterMode.LAND,
        CopterMode.POSHOLD,
        CopterMode.BRAKE,
        CopterMode.GUIDED_NOGPS,
    }
)
"""The modes this autopilot flies; the others are refused with a reason."""

CORE_MODE: dict[CopterMode, FlightMode] = {
    CopterMode.STABILIZE: FlightMode.HOLD,  # on the ground only: there is no pilot (RC) to stabilise for
    CopterMode.ALT_HOLD: FlightMode.ALTCTL,
    CopterMode.AUTO: FlightMode.MISSION,
    CopterMode.GUIDED: FlightMode.HOLD,
    CopterMode.LOITER: FlightMode.HOLD,
    CopterMode.RTL: FlightMode.RTL,
    CopterMode.CIRCLE: FlightMode.ORBIT,
    CopterMode.LAND: FlightMode.LAND,
    CopterMode.POSHOLD: FlightMode.POSCTL,
    CopterMode.BRAKE: FlightMode.HOLD,
    CopterMode.GUIDED_NOGPS: FlightMode.HOLD,  # until attitude targets come (they fly on OFFBOARD)
}
"""The core mode an ArduCopter mode starts on."""

STICK_CORE_MODE: dict[CopterMode, FlightMode] = {
    CopterMode.STABILIZE: FlightMode.STABILIZED,
    CopterMode.ALT_HOLD: FlightMode.ALTCTL,
    CopterMode.LOITER: FlightMode.POSCTL,
    CopterMode.POSHOLD: FlightMode.POSCTL,
}
"""The core mode an ArduCopter pilot mode flies on while RC input (RC_CHANNELS_OVERRIDE) is in force."""
ALT_HOLDING: frozenset[CopterMode] = frozenset({CopterMode.ALT_HOLD, CopterMode.LOITER, CopterMode.POSHOLD})
"""Pilot modes whose throttle stick is a climb rate around mid stick (``THR_DZ``)."""
ATTITUDE_TARGETS: frozenset[CopterMode] = frozenset({CopterMode.GUIDED, CopterMode.GUIDED_NOGPS})
"""Modes that fly SET_ATTITUDE_TARGET."""

_COMPATIBLE: dict[CopterMode, frozenset[FlightMode]] = {
    CopterMode.STABILIZE: frozenset({FlightMode.HOLD, FlightMode.STABILIZED}),
    CopterMode.ALT_HOLD: frozenset({FlightMode.ALTCTL}),
    CopterMode.AUTO: frozenset({FlightMode.MISSION, FlightMode.HOLD}),  # the core holds at the mission's end
    CopterMode.GUIDED: frozenset({FlightMode.HOLD, FlightMode.TAKEOFF, FlightMode.OFFBOARD}),
    CopterMode.LOITER: frozenset({FlightMode.HOLD, FlightMode.POSCTL}),
    CopterMode.RTL: frozenset({FlightMode.RTL}),
    CopterMode.CIRCLE: frozenset({FlightMode.ORBIT}),
    CopterMode.LAND: frozenset({FlightMode.LAND}),
    CopterMode.POSHOLD: frozenset({FlightMode.POSCTL}),
    CopterMode.BRAKE: frozenset({FlightMode.HOLD}),
    CopterMode.GUIDED_NOGPS: frozenset({FlightMode.HOLD, FlightMode.OFFBOARD}),
}
"""While the core is in one of these, the ArduCopter mode asked for is still the one shown."""

SHOWN_FOR_CORE: dict[FlightMode, CopterMode] = {
    FlightMode.MANUAL: CopterMode.STABILIZE,
    FlightMode.STABILIZED: CopterMode.STABILIZE,
    FlightMode.ALTCTL: CopterMode.ALT_HOLD,
    FlightMode.POSCTL: CopterMode.POSHOLD,
    FlightMode.OFFBOARD: CopterMode.GUIDED,
    FlightMode.TAKEOFF: CopterMode.GUIDED,
    FlightMode.HOLD: CopterMode.LOITER,
    FlightMode.MISSION: CopterMode.AUTO,
    FlightMode.RTL: CopterMode.RTL,
    FlightMode.LAND: CopterMode.LAND,
    FlightMode.ORBIT: CopterMode.CIRCLE,
}
"""What ArduCopter would call a core mode entered without an ArduCopter mode request (a failsafe...)."""

ARMABLE: frozenset[CopterMode] = frozenset(
    {
        CopterMode.STABILIZE,
        CopterMode.ALT_HOLD,
        CopterMode.GUIDED,
        CopterMode.LOITER,
        CopterMode.POSHOLD,
        CopterMode.GUIDED_NOGPS,
    }
)
"""ArduCopter refuses to arm in AUTO, RTL, LAND, CIRCLE and BRAKE ("Mode not armable")."""

USER_TAKEOFF: frozenset[CopterMode] = frozenset({CopterMode.GUIDED})
"""Modes in which NAV_TAKEOFF (a relative altitude) is obeyed."""


def copter_mode(number: float) -> CopterMode | None:
    """The mode of a ``custom_mode`` / DO_SET_MODE param2 value; None for numbers ArduCopter does not have."""
    try:
        return CopterMode(int(number))
    except (ValueError, OverflowError):
        return None


class ModeTracker:
    """The ArduCopter mode shown for the core's mode (server thread only).

    Starts in STABILIZE, as ArduCopter boots. ``select`` records a mode the vehicle accepted; ``shown``
    keeps it while the core runs one of its core modes and otherwise follows the core.
    """

    def __init__(self) -> None:
        self.selected = CopterMode.STABILIZE

    def select(self, mode: CopterMode) -> None:
        self.selected = mode

    def shown(self, core: FlightMode) -> CopterMode:
        if core not in _COMPATIBLE[self.selected]:
            self.selected = SHOWN_FOR_CORE[core]
        return self.selected
