"""Validation of inputs from outside (MAVLink, tests): finiteness, mission items."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

from harness.autopilot.api import MavCmd, MissionItem, MissionKind
from harness.autopilot.navigator import SUPPORTED_MISSION_COMMANDS

_FENCE = frozenset(
    {
        MavCmd.NAV_FENCE_RETURN_POINT,
        MavCmd.NAV_FENCE_POLYGON_VERTEX_INCLUSION,
        MavCmd.NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
        MavCmd.NAV_FENCE_CIRCLE_INCLUSION,
        MavCmd.NAV_FENCE_CIRCLE_EXCLUSION,
    }
)


def finite(values: Iterable[float]) -> bool:
    return all(math.isfinite(v) for v in values)


def check_mission(items: Sequence[MissionItem], kind: MissionKind) -> str:
    """'' when the items are acceptable, else why not ('unsupported …' for unknown commands)."""
    allowed = (
        SUPPORTED_MISSION_COMMANDS
        if kind == MissionKind.MISSION
        else (_FENCE if kind == MissionKind.FENCE else frozenset({MavCmd.NAV_RALLY_POINT}))
    )
    for i, it in enumerate(items):
        if it.seq != i:
            return f"item {i} has sequence number {it.seq}; items must be numbered 0..{len(items) - 1}"
        if it.command not in allowed:
            return f"unsupported command {it.command} in item {i} of the {kind.name.lower()}"
        # NaN in params 1-4 means "unchanged" in MAVLink; coordinates must be real
        if not finite([float(it.x), float(it.y), it.z]):
            return f"item {i}: coordinates are not finite"
        if it.is_global and (abs(it.lat_deg) > 90.0 or abs(it.lon_deg) > 180.0):
            return f"item {i}: latitude/longitude out of range ({it.lat_deg}, {it.lon_deg})"
        if any(math.isinf(v) for v in (it.param1, it.param2, it.param3, it.param4)):
            return f"item {i}: infinite parameter"
    return ""
