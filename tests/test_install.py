"""The user's path (issue 32): the package built as users get it, installed into a fresh virtual environment and
used from a folder outside the checkout — the demo, a MAVSDK mission flown byte-identical to this checkout's
install for the same seed, a user project's own pytest suite through the plugin, and the same from the sdist.

``python -m build`` makes the sdist and then the wheel from the sdist (so the wheel proves the sdist complete);
each is installed into its own venv with pip, as a user's CI would. Slow (two builds with the compiled core, two
installs): marked ``install``; CI runs it.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
import venv
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

from harness.pytest_plugin import RunRecord, run_harness
from harness.simclock.shim import SHIMS

pytestmark = [pytest.mark.install, pytest.mark.sim]
ROOT = Path(__file__).resolve().parents[1]
USER_PROJECT = ROOT / "tests" / "data" / "user_project"
MISSION, SEED, DURATION_S = "takeoff_and_land.py", 5, 16.0


@dataclass
class Install:
    """A fresh venv with the package installed from ``artifact``, and a folder of the user's outside the checkout."""

    venv: Path
    artifact: Path
    home: Path
    """The user's folder (the working directory of everything run here)."""
    cache: Path
    """XDG_CACHE_HOME of the runs: the sim-time shim must not be built there (the package carries it)."""

    @property
    def bin(self) -> Path:
        return self.venv / "bin"

    def env(self) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "VIRTUAL_ENV", "HARNESS_"))}
        env.update(PATH=f"{self.bin}{os.pathsep}{env.get('PATH', '')}", VIRTUAL_ENV=str(self.venv))
        env["XDG_CACHE_HOME"] = str(self.cache)
        env.setdefault("PIP_CACHE_DIR", str(Path.home() / ".cache" / "pip"))  # pip keeps the machine's cache
        return env

    def run(self, *cmd: str | Path, timeout_s: float = 900.0, check: bool = True) -> subprocess.CompletedProcess[str]:
        proc = subprocess.run(
            [str(c) for c in cmd], cwd=self.home, env=self.env(), capture_output=True, text=True, timeout=timeout_s
        )
        if check and proc.returncode != 0:
            pytest.fail(f"{shlex.join(str(c) for c in cmd)} exited {proc.returncode}:\n{proc.stdout}\n{proc.stderr}")
        return proc

    def fly(self, out: Path) -> RunRecord:
        """The reference mission from the installed examples, with the seed and duration of the editable run."""
        self.run(self.bin / "harness", "examples", "copy", MISSION, "--force")
        cmd = ["run", "--mission", MISSION, "--vehicles", "1", "--seed", str(SEED), "--duration", str(DURATION_S)]
        proc = self.run(self.bin / "harness", *cmd, "--out", out, check=False)
        return RunRecord(out, proc.returncode, proc.stdout, proc.stderr)


@pytest.fixture(scope="module")
def dist(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(wheel, sdist) built from this checkout as a release would be."""
    out = tmp_path_factory.mktemp("dist")
    subprocess.run(
        [sys.executable, "-m", "build", "--outdir", str(out), str(ROOT)],
        check=True,
        capture_output=True,
        timeout=1800,
    )
    (wheel,) = out.glob("uav_harness-*.whl")
    (sdist,) = out.glob("uav_harness-*.tar.gz")
    return wheel, sdist


def _install(tmp: Path, artifact: Path) -> Install:
    env = tmp / "venv"
    venv.EnvBuilder(with_pip=True).create(env)
    inst = Install(env, artifact, tmp / "user", tmp / "cache")
    inst.home.mkdir()
    inst.run(env / "bin" / "python", "-m", "pip", "install", "-q", str(artifact), timeout_s=1800)
    return inst


@pytest.fixture(scope="module")
def from_wheel(dist: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Install]:
    yield _install(tmp_path_factory.mktemp("wheel"), dist[0])


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> RunRecord:
    """The same mission and seed flown by the install these tests run in (the checkout's)."""
    run = run_harness(
        tmp_path_factory.mktemp("editable") / "run",
        ROOT / "missions" / MISSION,
        vehicles=1,
        seed=SEED,
        duration_s=DURATION_S,
    )
    assert run.summary["status"] in ("ok", "failed"), run.message  # the duration may end it mid-mission
    assert run.vehicle(0).max_altitude_m > 2.0, "the reference flight took off"
    return run


def _same_flight(run: RunRecord, reference: RunRecord) -> None:
    assert run.summary["status"] == reference.summary["status"], run.message
    got = [(m["t_s"], m["pos_ned_m"], m["vel_ned_m_s"]) for m in run.vehicle(0).track]
    want = [(m["t_s"], m["pos_ned_m"], m["vel_ned_m_s"]) for m in reference.vehicle(0).track]
    assert len(got) == len(want) > 100
    first = next((i for i, (a, b) in enumerate(zip(got, want, strict=True)) if a != b), None)
    assert first is None, (
        f"the installed package's flight differs at t={got[first][0]} s: {got[first]} vs {want[first]}"
    )


def test_the_wheel_carries_what_a_run_needs(dist: tuple[Path, Path]) -> None:
    names = zipfile.ZipFile(dist[0]).namelist()
    for built in SHIMS:
        assert {f"harness/simclock/{path.name}" for path in built.files()} <= set(names), f"{built.stem}'s sources"
        assert any(re.fullmatch(rf"harness/simclock/{built.stem}-[0-9a-f]{{16}}\.so", n) for n in names), built.stem
    assert {"harness/py.typed", "harness/examples/swarm_demo.py", "harness/examples/takeoff_and_land.py"} <= set(names)
    assert "harness/autopilot/params_data/copter_params.tsv" in names
    assert any(n.startswith("harness/fdm/models/") and n.endswith(".xml") for n in names), "the JSBSim model"


def test_installed_wheel_flies_the_demo_and_the_users_missions(from_wheel: Install, reference: RunRecord) -> None:
    assert not from_wheel.home.is_relative_to(ROOT)
    version = from_wheel.run(from_wheel.bin / "harness", "--version").stdout
    assert re.fullmatch(r"harness \d+\.\d+\.\d+\n", version), version
    listing = from_wheel.run(from_wheel.bin / "harness", "examples").stdout
    assert "swarm_demo.py" in listing and "takeoff_and_land.py" in listing

    demo = from_wheel.run(from_wheel.bin / "harness", "demo", "--out", "runs/demo", timeout_s=1200, check=False)
    assert demo.returncode == 0, demo.stdout + demo.stderr
    record = RunRecord(from_wheel.home / "runs" / "demo", demo.returncode, demo.stdout, demo.stderr)
    assert all(record.vehicle(i).landed and record.vehicle(i).max_altitude_m > 5 for i in range(3))

    run = from_wheel.fly(from_wheel.home / "runs" / "mavsdk")
    _same_flight(run, reference)
    assert "wall clock" not in run.mission_output(0), "MAVSDK ran on the sim clock"
    assert not list(from_wheel.cache.rglob("simtime-*.so")), "the shim came from the wheel, not a run-time build"


def test_a_user_projects_ci_workflow_passes_with_the_installed_wheel(from_wheel: Install) -> None:
    """The workflow of README's "Test your missions in CI", step by step: its `run:` lines in the user's folder,
    with the package it installs being this wheel."""
    project = from_wheel.home / "project"
    shutil.copytree(USER_PROJECT, project, ignore=shutil.ignore_patterns("ci.yml", "__pycache__"))
    workflow = yaml.safe_load((USER_PROJECT / "ci.yml").read_text())
    job = workflow["jobs"]["fly"]
    assert job["env"]["UAV_HARNESS"].startswith("uav-harness @ git+")
    steps = [s["run"] for s in job["steps"] if "run" in s]
    assert steps == ['pip install "$UAV_HARNESS" pytest', "pytest -q"]
    env = from_wheel.env() | {"UAV_HARNESS": str(from_wheel.artifact)}
    for step in steps:
        proc = subprocess.run(["bash", "-c", step], cwd=project, env=env, capture_output=True, text=True, timeout=1200)
        assert proc.returncode == 0, f"{step}:\n{proc.stdout}\n{proc.stderr}"
    assert "1 passed" in proc.stdout, proc.stdout


def test_installed_sdist_flies_the_same_flight(
    dist: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory, reference: RunRecord
) -> None:
    inst = _install(tmp_path_factory.mktemp("sdist"), dist[1])
    run = inst.fly(inst.home / "runs" / "mavsdk")
    _same_flight(run, reference)


def test_the_readme_shows_the_user_project_verbatim() -> None:
    readme = (ROOT / "README.md").read_text()
    for name in ("test_my_mission.py", "ci.yml"):
        text = (USER_PROJECT / name).read_text()
        assert text.strip() in readme, f"README's 'Test your missions in CI' must show {name} as it is tested"
