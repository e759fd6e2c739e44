"""What the package carries for users (``harness.bundled``): the example missions, listed and copied by
``harness examples``, and ``harness --version``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from harness.bundled import DEMO, copy_examples, example, examples, examples_dir
from harness.cli import main
from harness.core.errors import ScenarioError
from harness.simclock import shim

ROOT = Path(__file__).resolve().parents[1]


def test_every_mission_of_the_checkout_is_an_example_with_a_summary() -> None:
    names = {e.name for e in examples()}
    assert names == {p.name for p in (ROOT / "missions").glob("*.py") if not p.name.startswith("_")}
    assert DEMO in names and "takeoff_and_land.py" in names
    assert all(e.summary and not e.summary.startswith(" ") for e in examples())
    assert example("takeoff_and_land").path.read_bytes() == (ROOT / "missions" / "takeoff_and_land.py").read_bytes()


def test_examples_are_copied_into_the_users_folder_never_over_their_files(tmp_path: Path) -> None:
    (copied,) = copy_examples(["hover.py"], tmp_path / "mine")
    assert copied == tmp_path / "mine" / "hover.py"
    assert copied.read_bytes() == (examples_dir() / "hover.py").read_bytes()
    copied.write_text("# my edits\n")
    with pytest.raises(ScenarioError, match=r"hover\.py exists already: remove it, or add --force to overwrite it$"):
        copy_examples(["hover.py"], tmp_path / "mine")
    assert copied.read_text() == "# my edits\n"
    copy_examples(["hover"], tmp_path / "mine", force=True)
    assert copied.read_bytes() == (examples_dir() / "hover.py").read_bytes()
    with pytest.raises(ScenarioError, match=r"^no example mission 'nope\.py'; `harness examples` lists them \(\d+\)$"):
        copy_examples(["hover.py", "nope.py"], tmp_path / "other")
    assert not (tmp_path / "other").exists(), "nothing copied when one name is wrong"


def test_harness_examples_lists_and_copies_from_the_command_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    assert main(["examples"]) == 0
    out = capsys.readouterr().out
    assert f"{len(examples())} example missions in {examples_dir()}" in out
    assert any(line.startswith("takeoff_and_land.py ") for line in out.splitlines())
    monkeypatch.chdir(tmp_path)
    assert main(["examples", "copy", "takeoff_and_land.py", "orbit.py"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["orbit.py", "takeoff_and_land.py"]
    assert main(["examples", "copy", "--all", "--to", "all"]) == 0
    assert len(list((tmp_path / "all").glob("*.py"))) == len(examples())
    assert main(["examples", "copy"]) == 2
    assert "name the examples to copy" in capsys.readouterr().err


def test_version_is_the_installed_distributions() -> None:
    from importlib.metadata import version

    out = subprocess.run([sys.executable, "-m", "harness.cli", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout == f"harness {version('uav-harness')}\n"


@pytest.mark.skipif(shim.compiler() is None, reason="no C compiler: the install could not build the shim")
def test_the_install_built_the_sim_time_shim_and_runs_use_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    for built in shim.SHIMS:
        assert shim.packaged_path(built).is_file(), f"setup.py builds {built.stem} beside its sources"
        assert shim.build(built) == shim.packaged_path(built)
    assert not list(tmp_path.rglob("*.so")), "nothing compiled at run time"
