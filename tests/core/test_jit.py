"""The compiled kernels (``harness.core.jit``) in fresh processes: they work without a writable cache directory,
several processes compiling the same kernels at once into an empty cache all succeed with the same results,
and the processes that do not step vehicles do not import numba. (All on the pure-Python modules,
``HARNESS_PURE=1``: where the mypyc-compiled core runs numba is not used, ``tests/core/test_native.py``.)"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# a few kernels of the cascade, called as the flight core calls them; prints their results' bits
PROBE = """
import sys
from harness.autopilot.control import thrust_to_attitude
from harness.autopilot.inner import mix_quad_x
q, n = thrust_to_attitude((0.1, -0.05, -0.5), 0.3)
m, sp, sn = mix_quad_x(0.6, 0.0, 0.5, 0.5, 0.05)
print([x.hex() for x in (*q, n, *m)], sp, sn)
print("numba" in sys.modules)
"""


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH", "")]))
    env["HARNESS_PURE"] = "1"  # numba compiles the kernels only where mypyc's compiled core does not run
    return env | extra


def _probe(env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=240)


def _cache_files(d: Path) -> list[Path]:
    return [p for p in d.rglob("*") if p.suffix in (".nbi", ".nbc")]


def test_no_writable_cache_dir_falls_back_to_tmp_then_to_memory(tmp_path: Path) -> None:
    blocked = tmp_path / "not-a-dir"
    blocked.write_text("")  # numba's user-wide cache directory would be under a file: unusable
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    # the source tree's __pycache__ left out of numba's locators (as on a read-only install)
    base = _env(XDG_CACHE_HOME=str(blocked), TMPDIR=str(tmp))
    fallback = _probe(base | {"NUMBA_CACHE_LOCATOR_CLASSES": "UserProvidedCacheLocator,UserWideCacheLocator"})
    assert fallback.returncode == 0, fallback.stderr
    cached = _cache_files(tmp / f"harness-numba-cache-{os.getuid()}")
    assert {p.suffix for p in cached} == {".nbi", ".nbc"}
    # no usable locator at all: compiled in memory, one warning line per kernel, same results
    memory = _probe(base | {"NUMBA_CACHE_LOCATOR_CLASSES": "UserWideCacheLocator"})
    assert memory.returncode == 0, memory.stderr
    assert "compiling it in memory" in memory.stderr
    assert memory.stdout == fallback.stdout


def test_concurrent_first_compiles_agree(tmp_path: Path) -> None:
    env = _env(NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    procs = [
        subprocess.Popen([sys.executable, "-c", PROBE], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        for _ in range(3)
    ]
    outs = [p.communicate(timeout=240) for p in procs]
    assert [p.returncode for p in procs] == [0, 0, 0], [e.decode() for _, e in outs]
    assert len({o for o, _ in outs}) == 1
    assert _cache_files(tmp_path / "cache")
    # and a later process loads what they wrote
    again = _probe(env)
    assert again.returncode == 0 and again.stdout.encode() == outs[0][0]


def test_only_vehicle_stepping_processes_import_numba() -> None:
    def imports_numba(code: str) -> bool:
        code += "; import sys; print('numba' in sys.modules)"
        out = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        return out.stdout.strip() == "True"

    # the CLI (harness --help), a mission process, the network subscriber, the scenario layer (which reads the
    # sensors' configuration), the sweep driver, the launcher's module and the MAVLink package (the plan's
    # check reads its parameter tables before the launcher chooses whether to compile): no
    for module in (
        "harness.cli",
        "harness.autopilot.mavlink",
        "harness.simclock.mission",
        "harness.net.subscriber",
        "harness.scenario.config",
        "harness.sweep.runner",
        "harness.run.launcher",
    ):
        assert not imports_numba(f"import {module}"), module
    # what steps autopilots and sensors: the autopilot host, the physics once it has made its vehicles
    assert imports_numba("import harness.autopilot.sitl")
    physics = "from harness.fdm.physics import Physics, PhysicsConfig"
    assert not imports_numba(physics)
    assert imports_numba(f"{physics}; Physics(PhysicsConfig(n_vehicles=1))")


def test_plain_python_kernels_give_the_same_bits_without_numba() -> None:
    compiled = _probe(_env())
    plain = _probe(_env(HARNESS_JIT="0"))
    assert compiled.returncode == 0 and plain.returncode == 0, compiled.stderr + plain.stderr
    bits, numba_loaded = compiled.stdout.splitlines()
    assert plain.stdout.splitlines() == [bits, "False"] and numba_loaded == "True"


def test_prefer_decides_before_the_first_kernel_only() -> None:
    def run(code: str, **env: str) -> str:
        code = f"import sys; from harness.core import jit; {code}; print(jit.ENABLED, 'numba' in sys.modules)"
        out = subprocess.run([sys.executable, "-c", code], env=_env(**env), capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        return out.stdout.strip()

    # one vehicle: plain Python, numba never imported
    assert run("jit.prefer(False); import harness.autopilot.flight") == "False False"
    # too late once a kernel exists (its state arrays are made for it), and HARNESS_JIT has the last word
    assert run("import harness.autopilot.flight; jit.prefer(False)") == "True True"
    assert run("jit.prefer(False); import harness.autopilot.flight", HARNESS_JIT="1") == "True True"
