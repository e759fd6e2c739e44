"""The documentation against the code and the repository: every ``HARNESS_*`` variable and every scenario key the
loader accepts is on ``docs/configuration.md``, every link of the README and of ``docs/`` resolves, and nothing
tracked refers to a file outside the repository."""

from __future__ import annotations

import dataclasses
import re
import shlex
import subprocess
from pathlib import Path

import pytest

from harness.net.builtin import RadioConfig
from harness.net.ns3model import Ns3Config
from harness.scenario import config

ROOT = Path(__file__).resolve().parents[1]
CONFIGURATION = ROOT / "docs" / "configuration.md"
VARIABLE = re.compile(r"\bHARNESS_[A-Z0-9_]+\b")


def variables_in_code() -> set[str]:
    """Every ``HARNESS_*`` name in the package (Python and C) and in the build and setup scripts."""
    files = [*ROOT.joinpath("harness").rglob("*.py"), *ROOT.joinpath("harness").rglob("*.c")]
    files += [ROOT / "setup.py", ROOT / "dev.py"]
    return {name for f in files for name in VARIABLE.findall(f.read_text(encoding="utf-8"))}


def scenario_keys() -> set[str]:
    """Every key the scenario loader accepts, as ``docs/configuration.md`` writes it, from the loader's own tables."""
    keys = {k for k in config._TOP if k not in config._SECTIONS}
    keys |= {f"{section}.{k}" for section, allowed in config._SECTIONS.items() for k in allowed}
    keys |= {f"vehicles.{k}" for k in config._VEHICLES_TABLE}
    keys |= {f"vehicles[i].{k}" for k in config._VEHICLE}
    for model in (RadioConfig, Ns3Config):
        keys |= {f"network.params.{f.name}" for f in dataclasses.fields(model)}
    return keys


def documented_names(text: str) -> set[str]:
    """The names written in code spans on the page (``HARNESS_RUN_DIR``, ``world.lat_deg``, ``vehicles[i].args``)."""
    return {span.strip() for span in re.findall(r"`([^`\n]+)`", text)}


def test_every_harness_variable_in_the_code_is_on_the_configuration_page() -> None:
    found = variables_in_code()
    assert {"HARNESS_RUN_DIR", "HARNESS_PURE", "HARNESS_SIMTIME_TRACE", "HARNESS_MAVSDK_GRPC"} <= found
    missing = sorted(found - documented_names(CONFIGURATION.read_text(encoding="utf-8")))
    assert not missing, f"docs/configuration.md does not list {missing}"


def test_every_scenario_key_the_loader_accepts_is_on_the_configuration_page() -> None:
    keys = scenario_keys()
    assert {"seed", "rates.phase_every", "vehicles.spacing_m", "vehicles[i].spawn_ned_m"} <= keys
    assert {"network.params.bit_rate_bps", "network.params.standard"} <= keys
    missing = sorted(keys - documented_names(CONFIGURATION.read_text(encoding="utf-8")))
    assert not missing, f"docs/configuration.md does not list the scenario keys {missing}"


def test_the_configuration_page_names_no_variable_or_key_that_does_not_exist() -> None:
    names = documented_names(CONFIGURATION.read_text(encoding="utf-8"))
    stale = sorted(n for n in names if VARIABLE.fullmatch(n) and n not in variables_in_code())
    assert not stale, f"docs/configuration.md lists variables nothing reads: {stale}"


def markdown_pages() -> list[Path]:
    return [ROOT / "README.md", *sorted(ROOT.joinpath("docs").glob("*.md"))]


LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
PAGE_NAME = re.compile(r"(?<![\w/.-])docs/[\w.-]+\.(?:md|png)\b")


def broken_links(page: Path) -> list[str]:
    """The relative links of a Markdown page (``[text](target)``) and the ``docs/…`` pages it names that do not exist."""
    text = page.read_text(encoding="utf-8")
    broken = []
    for target in LINK.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue  # a URL (https:, mailto:) or an anchor on the same page
        path = target.split("#", 1)[0]
        if not (page.parent / path).exists():
            broken.append(target)
    broken += [name for name in PAGE_NAME.findall(text) if not (ROOT / name).exists()]
    return broken


def test_every_relative_link_of_the_readme_and_the_docs_resolves() -> None:
    pages = markdown_pages()
    assert ROOT / "docs" / "configuration.md" in pages and len(pages) > 10
    broken = {str(p.relative_to(ROOT)): b for p in pages if (b := broken_links(p))}
    assert not broken, f"links to files that do not exist: {broken}"


def test_the_link_check_sees_a_broken_link(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(
        "[ok](page.md) [gone](missing.md#part) ![img](nope.png) [web](https://example.com/x.md) [here](#top)\n"
        "see `docs/no-such-page.md` and `docs/design.md`\n"
    )
    assert broken_links(page) == ["missing.md#part", "nope.png", "docs/no-such-page.md"]


# The design notes of the team live outside the repository; what the code needs from them is in docs/.
OUTSIDE = re.compile(r"\.\./shared\b|(?<![\w.-])/?shared/[A-Z]+\.md\b|\b(?:DESIGN|STYLE|MAVLINK)\.md\b")


def outside_references(text: str) -> list[str]:
    return [m.group(0) for m in OUTSIDE.finditer(text)]


def test_no_tracked_file_refers_to_a_file_outside_the_repository() -> None:
    tracked = subprocess.run(
        ["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True, text=True
    ).stdout.split("\0")
    if not any(tracked):
        pytest.skip("not a git checkout: no list of tracked files")
    found = {}
    for name in filter(None, tracked):
        try:
            text = (ROOT / name).read_text(encoding="utf-8")
        except (UnicodeDecodeError, FileNotFoundError):
            continue  # a binary file (view.png), or one deleted in the work tree
        if refs := outside_references(text):
            found[name] = refs
    assert not found, f"references to files outside the repository (put what is needed in docs/): {found}"


def test_the_outside_reference_check_tells_a_note_from_a_page_of_docs() -> None:
    note, style, up = "DESIGN" + ".md", "STYLE" + ".md", ".." + "/shared"  # not written whole: this file is tracked
    assert outside_references(f"see {up}/{style} and {note}, and /shared/{note}") == [
        up,
        style,
        note,
        f"/shared/{note}",
    ]
    assert outside_references("see docs/design.md, docs/mavlink.md and --out /shared/runs/wind") == []


def readme_commands() -> list[list[str]]:
    """The ``harness`` command lines of the README's shell blocks, continuation lines joined, comments and
    the mission's arguments after ``--`` left out."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    commands = []
    for block in re.findall(r"```sh\n(.*?)```", text, flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            words = shlex.split(line, comments=True)
            if words and words[0] in ("harness", ".venv/bin/harness"):
                commands.append(words[1 : words.index("--")] if "--" in words else words[1:])
    return commands


def test_every_harness_command_of_the_readme_parses() -> None:
    from harness.cli import build_parser

    parser = build_parser()
    commands = readme_commands()
    assert {"run", "sitl", "sweep", "join", "view", "examples"} <= {c[0] for c in commands}, commands
    for words in commands:
        try:
            _, unknown = parser.parse_known_args(words)
        except SystemExit:
            pytest.fail(f"README: `harness {shlex.join(words)}` does not parse (see the error above)")
        assert not unknown, f"README: `harness {shlex.join(words)}`: unknown arguments {unknown}"
