"""Every Python >= 3.11 on this machine installs uav-harness and flies one MAVSDK mission (issue 32).

    python3 benchmarks/install_pythons.py                   # every python3.X found (pyenv's versions, PATH)
    python3 benchmarks/install_pythons.py /usr/bin/python3.12 …

For each interpreter: a wheel built from this checkout with that interpreter (``pip wheel``: the compiled core
and the sim-time shim are per interpreter), a fresh venv outside the checkout with the wheel installed, and
``harness run`` of the ``takeoff_and_land_native.py`` example (native MAVSDK API) from a folder outside the
checkout. Prints, per interpreter, the build, install and flight times and what the flight did.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MISSION = "takeoff_and_land_native.py"


def interpreters() -> list[Path]:
    found: dict[tuple[int, int], Path] = {}
    candidates = sorted(glob.glob(os.path.expanduser("~/.pyenv/versions/3.*/bin/python3")))
    candidates += [p for v in range(11, 20) if (p := shutil.which(f"python3.{v}"))]
    for c in candidates:
        out = subprocess.run([c, "-c", "import sys; print(*sys.version_info[:2])"], capture_output=True, text=True)
        if out.returncode == 0:
            major, minor = map(int, out.stdout.split())
            if (major, minor) >= (3, 11):
                found.setdefault((major, minor), Path(c))
    return [found[k] for k in sorted(found)]


def step(cmd: list[str], cwd: Path, env: dict[str, str] | None = None) -> float:
    t0 = time.monotonic()
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}: {(proc.stderr or proc.stdout)[-2000:]}")
    return time.monotonic() - t0


def try_one(python: Path, work: Path) -> str:
    dist, env_dir, user = work / "dist", work / "venv", work / "user"
    user.mkdir(parents=True)
    build_s = step([str(python), "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(dist), str(ROOT)], work)
    (wheel,) = dist.glob("uav_harness-*.whl")
    venv_s = step([str(python), "-m", "venv", str(env_dir)], work)
    install_s = step([str(env_dir / "bin" / "python"), "-m", "pip", "install", "-q", str(wheel)], work)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "VIRTUAL_ENV", "HARNESS_"))}
    harness = str(env_dir / "bin" / "harness")
    step([harness, "examples", "copy", MISSION], user, env)
    fly_s = step([harness, "run", "--vehicles", "1", "--mission", MISSION, "--out", "run", "--", "5"], user, env)
    summary = json.loads((user / "run" / "summary.json").read_text())
    v = summary["vehicles"][0]
    return (
        f"{wheel.name}: build {build_s:.0f} s, install {venv_s + install_s:.0f} s, flight {fly_s:.1f} s wall "
        f"({summary['sim_time_s']:.1f} s sim, status {summary['status']}, max altitude {v['max_altitude_m']:.2f} m, "
        f"landed {v['landed']}, mission exit {v['mission_exit_code']})"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("pythons", nargs="*", type=Path, help="interpreters (default: every python >= 3.11 found)")
    a = ap.parse_args()
    pythons = a.pythons or interpreters()
    failed = 0
    for python in pythons:
        with tempfile.TemporaryDirectory(prefix="uav-harness-py-") as tmp:
            try:
                print(f"{python}: {try_one(python, Path(tmp))}", flush=True)
            except (RuntimeError, OSError, ValueError, KeyError) as e:
                failed += 1
                print(f"{python}: FAILED: {e}", flush=True)
    print(f"{len(pythons) - failed} of {len(pythons)} interpreters installed uav-harness and flew {MISSION}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
