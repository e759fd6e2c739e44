"""The mypyc-compiled core (``harness.core.native``): the same bits as the pure-Python modules, used only when
its build matches the sources, and never together with numba."""

from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from harness.core import native

ROOT = Path(__file__).resolve().parents[2]

# a short fixed-seed flight of two vehicles (physics, sensors, autopilots, wind and turbulence): the digest of
# every frame and motor command, and which modules ran compiled
FLIGHT = """
import hashlib
import numpy as np
from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.core import jit, native
from harness.fdm.environment import WindConfig
from harness.fdm.frame import encode_frame
from harness.fdm.physics import Physics, PhysicsConfig
phys = Physics(PhysicsConfig(n_vehicles=2, seed=7, wind=WindConfig(steady_ned_m_s=(2.0, -1.0, 0.0), turbulence="moderate")))
aps = [Autopilot(AutopilotConfig(vehicle=v)) for v in range(2)]
frames, h = phys.frames(), hashlib.sha256()
for tick in range(250 * 8):
    motors = [ap.step(f) for ap, f in zip(aps, frames)]
    for f, m in zip(frames, motors):
        h.update(encode_frame(f))
        h.update(np.asarray(m, dtype=np.float64).tobytes())
    frames = phys.step(motors)
    if tick % 25 == 0:
        for ap in aps:
            if not ap.telemetry.state().armed and ap.telemetry.arming_check() == "":
                ap.action.arm()
                ap.action.takeoff(3.0)
print(h.hexdigest(), -frames[0].truth.pos_ned_m[2] > 1.0)
print(sorted(set(native.loaded().values())), jit.ENABLED)
"""


def _fly(**env: str) -> list[str]:
    e = {k: v for k, v in os.environ.items() if k not in ("HARNESS_PURE", "HARNESS_JIT")}
    e["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), e.get("PYTHONPATH", "")]))
    out = subprocess.run([sys.executable, "-c", FLIGHT], env=e | env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return out.stdout.splitlines()


def test_compiled_and_pure_python_fly_the_same_bits() -> None:
    pure = _fly(HARNESS_PURE="1", HARNESS_JIT="0")
    assert pure[0].endswith(" True") and pure[1] == "[False] False"
    assert _fly(HARNESS_PURE="1", HARNESS_JIT="1")[0] == pure[0]  # numba's kernels: the same bits too
    if native.decide(environ={})[0]:
        compiled = _fly()
        assert compiled == [pure[0], "[True] False"]  # every module compiled, numba not used
    elif os.environ.get("CI") == "true" and os.environ.get("HARNESS_PURE", "0") in ("", "0") and shutil.which("cc"):
        pytest.fail(f"CI, with a C compiler: the compiled core is not in use ({native.REASON}); dev.py builds it")


def _build(tmp_path: Path) -> tuple[Path, Path]:
    """A copy of the compiled modules' sources and a manifest that matches them."""
    pkg = tmp_path / "harness"
    for m in native.MODULES:
        dst = native.source_of(m, pkg)
        dst.parent.mkdir(parents=True, exist_ok=True)
        dst.write_bytes(native.source_of(m).read_bytes())
    manifest = pkg / "_native.json"
    manifest.write_text(json.dumps({"modules": native.digests(pkg)}))
    return pkg, manifest


def test_a_build_runs_only_while_its_sources_are_unchanged(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    pkg, manifest = _build(tmp_path)
    assert native.decide({}, manifest, pkg) == (True, "built")
    assert native.decide({"HARNESS_PURE": "1"}, manifest, pkg) == (False, "HARNESS_PURE is set")
    assert native.decide({}, tmp_path / "missing.json", pkg) == (False, "not built")
    with native.source_of("harness.autopilot.control", pkg).open("a") as f:
        f.write("# edited after the build\n")
    with caplog.at_level(logging.WARNING, logger=native.__name__):
        assert native.decide({}, manifest, pkg) == (False, "stale: harness.autopilot.control")
    assert len(caplog.records) == 1 and "harness.autopilot.control changed since the build" in caplog.text


def test_a_harness_module_outside_the_build_is_always_its_source() -> None:
    # an extension an earlier build left beside it (a module since dropped from MODULES) is never imported
    import harness.channel.machine
    import harness.run.launcher

    assert "harness.channel.machine" not in native.MODULES
    assert harness.channel.machine.__file__ and harness.channel.machine.__file__.endswith(".py")
    assert harness.run.launcher.__file__ and harness.run.launcher.__file__.endswith(".py")
