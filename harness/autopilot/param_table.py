"""Parameter tables as data: a firmware's full parameter list (names, types, defaults, ranges, units) parsed from
generated tab-separated text, for a personality to serve.

The format is firmware-neutral (``tools/gen_copter_params.py`` writes ArduCopter's from QGroundControl's
metadata into a module as one string, so that it ships with the package); ``#`` lines are comments, the
first other line names the columns::

    name  type  default  min  max  unit  flags        type: i (integer) or f (float); min/max: empty = none;
                                                      flags: r = read-only, - none

    table = parse_param_table(text)    # or load_param_table(path) for a file
    table.defs[0].name, table.ranges["WPNAV_SPEED"], "FORMAT_VERSION" in table.read_only
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

from harness.autopilot.params import ParamDef, ParamType
from harness.core.errors import ScenarioError

_COLUMNS = ("name", "type", "default", "min", "max", "unit", "flags")


@dataclass(frozen=True, slots=True)
class ParamTable:
    """One firmware's parameter list. ``defs`` carry no limits (min/max infinite); ``ranges`` holds the
    documented range of those that have one (a firmware may or may not enforce it)."""

    source: str
    """The table's header comment (where it came from, version, rules)."""
    defs: tuple[ParamDef, ...]
    ranges: dict[str, tuple[float, float]]
    read_only: frozenset[str]

    def __len__(self) -> int:
        return len(self.defs)


def _number(text: str, what: str) -> float | None:
    if not text:
        return None
    try:
        v = float(text)
    except ValueError:
        raise ScenarioError(f"parameter table: {what} {text!r} is not a number") from None
    if not math.isfinite(v):
        raise ScenarioError(f"parameter table: {what} {text!r} is not finite")
    return v


def load_param_table(path: Path) -> ParamTable:
    return parse_param_table(path.read_text(encoding="utf-8"), str(path))


@functools.cache
def parse_param_table(text: str, where: str = "parameter table") -> ParamTable:
    """Parse a table (once per text: vehicles share it)."""
    comments: list[str] = []
    defs: list[ParamDef] = []
    ranges: dict[str, tuple[float, float]] = {}
    read_only: set[str] = set()
    header = True
    for line in text.splitlines():
        if not line:
            continue
        if line.startswith("#"):
            comments.append(line[1:].strip())
            continue
        cols = line.split("\t")
        if header:
            if tuple(cols) != _COLUMNS:
                raise ScenarioError(f"{where}: columns {cols}, expected {list(_COLUMNS)}")
            header = False
            continue
        if len(cols) != len(_COLUMNS):
            raise ScenarioError(f"{where}: bad line {line!r}")
        name, kind, default, lo, hi, unit, flags = cols
        ptype = ParamType.INT32 if kind == "i" else ParamType.FLOAT
        d = _number(default, f"{name} default") or 0.0
        if ptype == ParamType.INT32 and not d.is_integer():
            raise ScenarioError(f"{where}: integer parameter {name} has the default {default}")
        defs.append(ParamDef(name, ptype, d, -math.inf, math.inf, unit))
        a, b = _number(lo, f"{name} min"), _number(hi, f"{name} max")
        if a is not None and b is not None:
            ranges[name] = (a, b)
        if "r" in flags:
            read_only.add(name)
    return ParamTable(" ".join(comments), tuple(defs), ranges, frozenset(read_only))
