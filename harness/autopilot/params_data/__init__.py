"""PX4's parameter metadata as data: names, types, defaults, ranges and units, no prose.

``px4_params.json`` is generated from QGroundControl's ``PX4ParameterFactMetaData.xml`` by ``generate.py``
(``python -m harness.autopilot.params_data.generate XML``); :func:`load` reads it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from importlib import resources


@dataclass(frozen=True, slots=True)
class MetaParam:
    name: str
    is_int: bool
    default: float
    min: float
    max: float
    unit: str
    reboot_required: bool


@dataclass(frozen=True, slots=True)
class Metadata:
    source: str
    """Where the table came from (repository, commit, date, firmware line)."""
    params: tuple[MetaParam, ...]


@cache
def load() -> Metadata:
    raw = json.loads(resources.files(__package__).joinpath("px4_params.json").read_text())
    params = tuple(
        MetaParam(name, kind == "I", float(default), float(lo), float(hi), unit, bool(reboot))
        for name, kind, default, lo, hi, unit, reboot in raw["params"]
    )
    return Metadata(raw["source"], params)
