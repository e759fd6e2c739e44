"""A mission's stdin: at end-of-file at once without ``--stdin`` (also for a selector, which /dev/null broke);
with ``harness run --stdin`` the terminal's lines reach the one mission, its prompts show, and the script's
wait for a line is a sim-time wait (the simulation goes on meanwhile)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from harness.pytest_plugin import run_harness

pytestmark = pytest.mark.sim

SELECTS_STDIN = """
import selectors
import sys
import time

sel = selectors.DefaultSelector()
sel.register(sys.stdin, selectors.EVENT_READ)
print("ready:", len(sel.select(5.0)))
print("line:", repr(sys.stdin.readline()))
try:
    input("name? ")
except EOFError:
    print("EOF")
"""

PROMPTS = """
import time

time.sleep(1.0)
t0 = time.time()
name = input("Your name? ")
print("hello %s after %.1f s of sim time" % (name, time.time() - t0))
"""


def test_without_the_flag_stdin_is_at_end_of_file(tmp_path: Path) -> None:
    script = tmp_path / "selects.py"
    script.write_text(SELECTS_STDIN)
    run = run_harness(tmp_path / "out", script, vehicles=1, duration_s=5)
    assert run.ok, run.message
    assert run.mission_output(0).splitlines()[-3:] == ["ready: 1", "line: ''", "name? EOF"]


def test_stdin_flag_hands_the_terminal_to_the_one_mission(tmp_path: Path) -> None:
    script = tmp_path / "prompts.py"
    script.write_text(PROMPTS)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "harness.cli", "run", "--mission", str(script), "--stdin", "--speed", "1"]
    proc = subprocess.Popen(
        [*cmd, "--duration", "30", "--out", str(out)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None and proc.stdin is not None
    seen = ""
    while "Your name? " not in seen:  # the prompt shows here before the script waits (no newline after it)
        ch = proc.stdout.read(1)
        assert ch, f"no prompt; stderr: {proc.stderr.read() if proc.stderr else ''}"
        seen += ch
    time.sleep(2.0)  # the user thinks for 2 s: sim time goes on at x1
    rest, err = proc.communicate("bob\n", timeout=120)
    assert proc.returncode == 0, err
    line = next(ln for ln in (seen + rest).splitlines() if "hello" in ln)
    waited = float(line.split(" after ")[1].split()[0])
    assert line.startswith("Your name? hello bob") and 0.0 < waited < 20.0  # sim time went on (slower under load)
    assert "hello bob" in (out / "mission-0.stdout").read_text()  # also in the run's record


def test_stdin_flag_needs_exactly_one_mission(tmp_path: Path) -> None:
    script = tmp_path / "prompts.py"
    script.write_text(PROMPTS)
    cmd = [sys.executable, "-m", "harness.cli", "run", "--mission", str(script), "--vehicles", "2", "--stdin"]
    proc = subprocess.run([*cmd, "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0 and "--stdin hands the terminal to one mission" in proc.stderr
