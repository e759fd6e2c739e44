"""``harness.cli.main`` called as a function (a test, a program embedding the harness) leaves the process as it
found it; the ``harness`` command itself ignores a late Ctrl-C while it exits (tests/run/test_sitl.py)."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

from harness.cli import main


def test_main_as_a_function_leaves_the_signal_handlers_as_it_found_them(tmp_path: Path) -> None:
    """A run command arms SIGINT/SIGTERM handlers for its clean stop; they must not stay behind as 'ignored',
    which every process started afterwards would inherit (a SIGTERM'd child then lives until SIGKILL)."""
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    argv = ["run", "--vehicles", "1", "--mission", str(tmp_path / "nope.py"), "--out", str(tmp_path / "r")]
    assert main(argv) == 2  # the mission does not exist: one line, after the run's stop handlers were armed
    assert {s: signal.getsignal(s) for s in before} == before
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    child.terminate()
    assert child.wait(30) == -signal.SIGTERM
