#!/usr/bin/env python3
"""Set up and run uav-harness from a fresh clone with nothing but Python >= 3.11.

    python3 dev.py demo     # create .venv, install (with the 3D view), fly a 3-vehicle swarm, plots + world.rrd
    python3 dev.py test     # create .venv, install with dev tools, then ruff + mypy + pytest

`test` also installs Debian's chromium (for the web-view test) when it is missing and apt-get can (root).

Both are idempotent: the virtual environment in .venv is reused once it is up to date.
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
import os
import shutil
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
PY = BIN / "python"
MAVPROXY = "MAVProxy==1.8.75"


def sh(*cmd: str | Path, check: bool = True) -> int:
    print("+", " ".join(str(c) for c in cmd), flush=True)
    return subprocess.run([str(c) for c in cmd], cwd=ROOT, check=check).returncode


def native_sources() -> bytes:
    """setup.py and the sources mypyc compiles (``harness.core.native.MODULES``, read by path: the package may not
    be installed): when one changes, the install is redone, so the compiled modules are rebuilt (a stale
    build would run as pure Python, slower, with a warning)."""
    spec = importlib.util.spec_from_file_location("_harness_native", ROOT / "harness" / "core" / "native.py")
    assert spec is not None and spec.loader is not None
    native = importlib.util.module_from_spec(spec)
    logging.getLogger("_harness_native").setLevel(logging.ERROR)  # its stale-build warning is this one's job
    spec.loader.exec_module(native)
    return (ROOT / "setup.py").read_bytes() + "".join(sorted(native.digests().values())).encode()


def setup(extras: str) -> None:
    if sys.version_info < (3, 11):  # noqa: UP036 - dev.py runs under whatever python3 the machine has
        sys.exit(f"uav-harness needs Python >= 3.11, this is {sys.version.split()[0]}")
    if not PY.exists():
        venv.EnvBuilder(with_pip=True).create(VENV)
    stamp = VENV / f".installed-{extras.replace(',', '-') or 'base'}"
    digest = hashlib.sha256((ROOT / "pyproject.toml").read_bytes() + MAVPROXY.encode() + native_sources()).hexdigest()
    if stamp.exists() and stamp.read_text() == digest:
        return
    sh(PY, "-m", "pip", "install", "-q", "--upgrade", "pip")
    sh(PY, "-m", "pip", "install", "-q", "-e", f".[{extras}]" if extras else ".")
    if (ROOT / "harness" / "_native.json").is_file():
        print("the per-vehicle core is compiled (mypyc, harness/core/native.py); HARNESS_PURE=1 runs it as Python")
    else:
        why = (
            "HARNESS_PURE is set"
            if os.environ.get("HARNESS_PURE", "0") not in ("", "0")
            else "no C compiler, or its build failed"
        )
        print(f"the per-vehicle core is not compiled ({why}): pure Python, same results")
    if "dev" in extras.split(","):
        # The MAVProxy test: MAVProxy's console needs only what the dev extra lists (pymavlink, pyserial,
        # defusedxml, pynmeagps); its declared opencv/vtk/matplotlib serve map and 3-D modules we do not load.
        sh(PY, "-m", "pip", "install", "-q", "--no-deps", MAVPROXY)
    stamp.write_text(digest)


def demo(args: list[str]) -> int:
    setup("view")
    code = sh(BIN / "harness", "demo", "--out", "runs/demo", *args, check=False)
    if (ROOT / "runs" / "demo" / "world.rrd").is_file():
        harness = BIN.relative_to(ROOT) / "harness"
        print(f"\nOpen its 3D view: {harness} view runs/demo   (no display: {harness} view runs/demo --web)")
    return code


def chromium() -> None:
    """The web-view test needs a headless Chromium: install Debian's when it is missing and we can."""
    if any(shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")):
        return
    if not shutil.which("apt-get") or not hasattr(os, "geteuid") or os.geteuid() != 0:
        print("chromium is missing and cannot be installed here (needs apt-get as root): the web-view test skips")
        return
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    for cmd in (["apt-get", "update", "-qq"], ["apt-get", "install", "-y", "-qq", "chromium"]):
        print("+", " ".join(cmd), flush=True)
        if subprocess.run(cmd, env=env, check=False).returncode:
            print("installing chromium failed: the web-view test fails under CI=true, skips elsewhere")
            return


def test(args: list[str]) -> int:
    setup("dev,ns3,view")  # CI tests the ns-3 network model and the 3D view too
    chromium()
    if sh(BIN / "ruff", "check", "harness", "tests", "benchmarks", "missions", "dev.py", check=False):
        return 1
    if sh(BIN / "ruff", "format", "--check", "harness", "tests", "benchmarks", "missions", "dev.py", check=False):
        return 1
    if sh(BIN / "mypy", check=False):
        return 1
    code = sh(PY, "-m", "pytest", "-q", *args, check=False)
    return 0 if code == 5 else code  # 5: no tests collected (an empty selection is not a failure)


def main() -> int:
    if len(sys.argv) < 2 or sys.argv[1] not in ("demo", "test"):
        print(__doc__)
        return 2
    cmd, rest = sys.argv[1], sys.argv[2:]
    return demo(rest) if cmd == "demo" else test(rest)


if __name__ == "__main__":
    sys.exit(main())
