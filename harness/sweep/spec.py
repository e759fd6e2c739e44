"""What a sweep runs: the cartesian product of seeds and ``--set`` values over one scenario file.

Pure and validated before anything starts. Every combination is checked by the scenario loader itself
(``harness.scenario.config.load_scenario`` with the ``--set`` values applied), so a sweep reports exactly
the one-line errors a scenario file would, prefixed with the ``--set`` that caused them.
"""

from __future__ import annotations

import hashlib
import itertools
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from harness.core.errors import ScenarioError
from harness.scenario.config import load_scenario, parse_value

_MAX_RUNS = 100_000
_MAX_NAME = 120


@dataclass(frozen=True)
class SweepParam:
    """One ``--set PATH=V1,V2,...``: the dotted path and each value as typed (text and parsed)."""

    path: str
    texts: tuple[str, ...]
    values: tuple[Any, ...]


@dataclass(frozen=True)
class RunSpec:
    """One run of a sweep: its directory name, seed and one value per swept parameter."""

    name: str
    seed: int
    sets: tuple[tuple[str, str], ...]
    """(dotted path, value as typed on the command line) — passed on as ``harness run --set PATH=TEXT``."""
    values: tuple[tuple[str, Any], ...]
    """(dotted path, parsed value) — the columns of results.csv."""

    def params(self) -> dict[str, Any]:
        return dict(self.values)


@dataclass(frozen=True)
class SweepSpec:
    scenario: Path
    seeds: tuple[int, ...]
    params: tuple[SweepParam, ...]
    runs: tuple[RunSpec, ...]

    def describe(self) -> dict[str, Any]:
        """The sweep as JSON (``DIR/sweep.json``)."""
        return {
            "scenario": str(self.scenario),
            "seeds": list(self.seeds),
            "parameters": [{"path": p.path, "values": list(p.values)} for p in self.params],
            "runs": [r.name for r in self.runs],
        }


def parse_seeds(text: str) -> tuple[int, ...]:
    """``0-9``, ``0,3,7`` or ``0-3,10`` (ranges inclusive) → the seeds in order, each once."""
    seeds: list[int] = []
    for part in (p.strip() for p in text.split(",")):
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if m is None:
            raise ScenarioError(f"--seeds {text}: {part!r} is not a seed or a range (e.g. 0-9 or 0,3,7)")
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) is not None else lo
        if hi < lo:
            raise ScenarioError(f"--seeds {text}: the range {part} runs backwards")
        if hi - lo >= _MAX_RUNS:
            raise ScenarioError(f"--seeds {text}: more than {_MAX_RUNS} seeds")
        for s in range(lo, hi + 1):
            if s in seeds:
                raise ScenarioError(f"--seeds {text}: seed {s} is given twice")
            seeds.append(s)
    return tuple(seeds)


def split_values(text: str) -> list[str]:
    """Split ``V1,V2,...`` at the commas that are not inside brackets, braces or quotes
    (``[0,0,0],[5,0,0]`` is two values)."""
    out: list[str] = []
    depth, quote, start = 0, "", 0
    for i, ch in enumerate(text):
        if quote:
            if ch == quote:
                quote = ""
        elif ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append(text[start:i].strip())
            start = i + 1
    out.append(text[start:].strip())
    return out


def parse_set(text: str) -> SweepParam:
    path, eq, values = text.partition("=")
    path = path.strip()
    if not eq or not path:
        raise ScenarioError(f"--set {text}: expected PATH=V1,V2,... e.g. --set wind.north_m_s=0,4,8")
    texts = split_values(values)
    if any(not t for t in texts):
        raise ScenarioError(f"--set {text}: an empty value (two commas in a row, or a trailing comma?)")
    if len(set(texts)) != len(texts):
        raise ScenarioError(f"--set {text}: a value is given twice")
    return SweepParam(path, tuple(texts), tuple(parse_value(t) for t in texts))


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._+-]+", "_", text).strip("_") or "_"


def run_name(seed: int, sets: Sequence[tuple[str, str]]) -> str:
    """The run's directory: ``seed-3_wind.north_m_s-4`` (stable for the same command, so a re-run finds it).

    Names longer than ``_MAX_NAME`` keep their start and end with a hash of the whole (file names are short)."""
    name = "_".join([f"seed-{seed}", *(f"{_slug(path)}-{_slug(text)}" for path, text in sets)])
    if len(name) <= _MAX_NAME:
        return name
    digest = hashlib.sha1(name.encode()).hexdigest()[:10]
    return f"{name[: _MAX_NAME - 11]}_{digest}"


def build_sweep(scenario: str | Path, seeds: str | None, sets: Sequence[str]) -> SweepSpec:
    """Parse and validate the whole sweep; raises :class:`ScenarioError` (one line) on the first mistake."""
    scenario = Path(scenario)
    base = load_scenario(scenario)  # the file itself first: its own errors without a --set prefix
    seed_list = parse_seeds(seeds) if seeds is not None else (base.seed,)
    params = tuple(parse_set(s) for s in sets)
    paths = [p.path for p in params]
    for path, instead in (("seed", "sweep seeds with --seeds"), ("out", "the sweep puts each run under --out")):
        if path in paths:
            raise ScenarioError(f"--set {path}: not a sweep parameter ({instead})")
    for path in paths:
        if paths.count(path) > 1:
            raise ScenarioError(f"--set {path}: given twice (list every value in one --set {path}=V1,V2,...)")
    total = len(seed_list)
    for p in params:
        total *= len(p.values)
    if total > _MAX_RUNS:
        raise ScenarioError(f"the sweep has {total} runs, more than {_MAX_RUNS}: narrow --seeds or --set")
    for p in params:  # every value once (the loader's message, with the --set that caused it)
        for text, value in zip(p.texts, p.values, strict=True):
            _validate(scenario, [(p.path, value)], f"--set {p.path}={text}")
    with_net = [p.path for p in params if p.path == "network.model"]
    runs: list[RunSpec] = []
    names: set[str] = set()
    for combo in itertools.product(*(list(zip(p.texts, p.values, strict=True)) for p in params)):
        chosen = [(p.path, value) for p, (_, value) in zip(params, combo, strict=True)]
        what = " ".join(f"--set {p.path}={t}" for p, (t, _) in zip(params, combo, strict=True))
        if len(params) > 1:  # values valid one by one may still clash (e.g. rates): check the combination
            _validate(scenario, chosen, what)
        _no_idle_network_params(scenario, params, chosen, what if with_net else "")
        for seed in seed_list:
            sets_text = tuple((p.path, t) for p, (t, _) in zip(params, combo, strict=True))
            name = run_name(seed, sets_text)
            if name in names:
                raise ScenarioError(f"two runs of the sweep would share the directory {name}: make the values distinct")
            names.add(name)
            runs.append(RunSpec(name, seed, sets_text, tuple(chosen)))
    return SweepSpec(scenario, seed_list, params, tuple(runs))


def _no_idle_network_params(
    scenario: Path, params: Sequence[SweepParam], chosen: list[tuple[str, Any]], what: str
) -> None:
    """A swept ``network.params.X`` in a run without a network model would change nothing: one line, not a
    sweep whose column means nothing."""
    swept = [p.path for p in params if p.path.startswith("network.params.")]
    if swept and load_scenario(scenario, sets=chosen).network == "none":
        where = f"{what}: " if what else ""
        raise ScenarioError(
            f"--set {swept[0]}: {where}the network model is 'none' in {scenario}, so network parameters change "
            'nothing; set network.model = "builtin" (or "ns3") in the file or add --set network.model=builtin'
        )


def _validate(scenario: Path, sets: list[tuple[str, Any]], what: str) -> None:
    try:
        load_scenario(scenario, sets=sets)  # network parameters included (scenario/limits.py)
    except ScenarioError as exc:
        text = str(exc)
        raise ScenarioError(text if text.startswith("--set ") else f"{what}: {text}") from None
