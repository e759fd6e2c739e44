#!/usr/bin/env python3
"""Set up and run uav-harness from a fresh clone with nothing but Python >= 3.11.

    python3 dev.py demo     # create .venv, install, run a 3-vehicle scenario and write its plots
    python3 dev.py test     # create .venv, install with dev tools, then ruff + mypy + pytest

Both are idempotent: the virtual environment in .venv is reused once it is up to date.
"""

from __future__ import annotations

import hashlib
import os
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


def setup(extras: str) -> None:
    if sys.version_info < (3, 11):  # noqa: UP036 - dev.py runs under whatever python3 the machine has
        sys.exit(f"uav-harness needs Python >= 3.11, this is {sys.version.split()[0]}")
    if not PY.exists():
        venv.EnvBuilder(with_pip=True).create(VENV)
    stamp = VENV / f".installed-{extras.replace(',', '-') or 'base'}"
    digest = hashlib.sha256((ROOT / "pyproject.toml").read_bytes() + MAVPROXY.encode()).hexdigest()
    if stamp.exists() and stamp.read_text() == digest:
        return
    sh(PY, "-m", "pip", "install", "-q", "--upgrade", "pip")
    sh(PY, "-m", "pip", "install", "-q", "-e", f".[{extras}]" if extras else ".")
    if "dev" in extras.split(","):
        # The MAVProxy test: MAVProxy's console needs only what the dev extra lists (pymavlink, pyserial,
        # defusedxml, pynmeagps); its declared opencv/vtk/matplotlib serve map and 3-D modules we do not load.
        sh(PY, "-m", "pip", "install", "-q", "--no-deps", MAVPROXY)
    stamp.write_text(digest)


def demo(args: list[str]) -> int:
    setup("")
    out = ROOT / "runs" / "demo"
    return sh(BIN / "harness", "demo", "--out", out, *args, check=False)


def test(args: list[str]) -> int:
    setup("dev,ns3")  # CI tests the ns-3 network model too
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
