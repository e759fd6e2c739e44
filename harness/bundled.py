"""What the package carries for its users: the example missions (``harness.examples``, from ``missions/``).

``harness examples`` lists them, ``harness examples copy NAME…`` copies them into a folder of the user's, and
``harness demo`` flies one. In a wheel they are package data of ``harness.examples``; in a checkout run without
an install they are ``missions/`` beside ``harness/``.
"""

from __future__ import annotations

import ast
import importlib.util
import shutil
from dataclasses import dataclass
from pathlib import Path

from harness.core.errors import ScenarioError

DEMO = "swarm_demo.py"
"""The mission ``harness demo`` flies."""


def examples_dir() -> Path:
    """The folder of the example missions, installed or in a checkout."""
    try:
        spec = importlib.util.find_spec("harness.examples")
    except (ImportError, ValueError):
        spec = None
    if spec is not None and spec.submodule_search_locations:
        for folder in spec.submodule_search_locations:
            if Path(folder, DEMO).is_file():
                return Path(folder)
    checkout = Path(__file__).resolve().parent.parent / "missions"
    if (checkout / DEMO).is_file():
        return checkout
    raise ScenarioError(
        "the example missions (harness.examples) are not installed: reinstall uav-harness "
        "(pip install --force-reinstall uav-harness)"
    )


@dataclass(frozen=True)
class Example:
    name: str
    """File name, e.g. ``takeoff_and_land.py``."""
    path: Path
    summary: str
    """The first line of its docstring."""


def examples() -> list[Example]:
    """Every example mission, by name."""
    out = []
    for path in sorted(examples_dir().glob("*.py")):
        if path.name.startswith("_"):
            continue
        doc = ast.get_docstring(ast.parse(path.read_bytes(), str(path))) or ""
        out.append(Example(path.name, path, doc.strip().splitlines()[0] if doc.strip() else ""))
    return out


def example(name: str) -> Example:
    """One example by file name (``.py`` may be left out); a ScenarioError naming the choices otherwise."""
    found = {e.name: e for e in examples()}
    key = name if name.endswith(".py") else f"{name}.py"
    if key not in found:
        raise ScenarioError(f"no example mission {name!r}; `harness examples` lists them ({len(found)})")
    return found[key]


def copy_examples(names: list[str], dest: Path, *, force: bool = False) -> list[Path]:
    """Copy the named examples into ``dest`` (created); an existing file is kept unless ``force``."""
    chosen = [example(n) for n in names]
    dest.mkdir(parents=True, exist_ok=True)
    out = []
    for ex in chosen:
        target = dest / ex.name
        if target.exists() and not force:
            raise ScenarioError(f"{target} exists already: remove it, or add --force to overwrite it")
        shutil.copyfile(ex.path, target)
        out.append(target)
    return out
