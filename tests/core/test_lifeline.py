"""harness.core.lifeline: a child that ties itself to its parent dies with it, whenever the parent dies.

Real processes: a middle process (the "parent") starts a Python child with ``tied_env`` and no
``preexec_fn``, as ``Children`` does; the test kills or ends the parent and watches the child.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from harness.core import lifeline
from tests.helpers import wait_until

# The child: optionally waits (the parent can die before it ties itself), ties itself, says so in a file,
# and would then live for a minute.
CHILD = """
import os, sys, time
time.sleep(float(sys.argv[2]))
from harness.core import lifeline
lifeline.hold_on()
with open(sys.argv[1], "w") as f:
    f.write("tied " + str(lifeline.PARENT_ENV in os.environ))
time.sleep(60)
"""
# The parent: starts the child as Children does, prints its pid, then waits or exits at once.
PARENT = """
import subprocess, sys, time
from harness.core import lifeline
child = subprocess.Popen(
    [sys.executable, "-c", sys.argv[1], sys.argv[2], sys.argv[3]],
    env=lifeline.tied_env({"PYTHONPATH": sys.argv[4]}),
    process_group=0,
)
print(child.pid, flush=True)
if sys.argv[5] == "wait":
    time.sleep(60)
"""
SRC = str(Path(__file__).resolve().parents[2])


def _alive(pid: int) -> bool:
    """Running (a zombie waiting for a reaper counts as gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _wait_gone(pid: int, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    return not _alive(pid)


def _parent(marker: Path, child_delay_s: float, then: str) -> tuple[subprocess.Popen[str], int]:
    proc = subprocess.Popen(
        [sys.executable, "-c", PARENT, CHILD, str(marker), str(child_delay_s), SRC, then],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    return proc, int(proc.stdout.readline())


def test_the_child_dies_when_its_parent_is_killed_after_it_tied_itself(tmp_path: Path) -> None:
    marker = tmp_path / "tied"
    parent, child = _parent(marker, 0.0, "wait")
    try:
        wait_until(marker.exists, 30.0, "the child to tie itself", poll_s=0.05)
        assert marker.read_text() == "tied False"  # tied, and its own children are not: the variable is gone
        assert _alive(child)
        parent.send_signal(signal.SIGKILL)
        parent.wait(10)
        assert _wait_gone(child, 5.0), "the child outlived its kill -9ed parent"
    finally:
        parent.kill()
        parent.wait()
        if _alive(child):
            os.kill(child, signal.SIGKILL)


def test_a_child_whose_parent_died_before_it_tied_itself_exits_at_once(tmp_path: Path) -> None:
    marker = tmp_path / "tied"
    parent, child = _parent(marker, 1.0, "exit")  # the parent is gone long before the child ties itself
    parent.wait(10)
    try:
        assert _wait_gone(child, 10.0), "the orphaned child kept running"
        assert not marker.exists(), "the orphaned child went on past hold_on()"
    finally:
        if _alive(child):
            os.kill(child, signal.SIGKILL)


def test_without_the_variable_nothing_is_tied() -> None:
    env = {k: v for k, v in os.environ.items() if k != lifeline.PARENT_ENV}
    code = "from harness.core import lifeline; lifeline.hold_on(); print('ran')"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=30)
    assert out.returncode == 0 and out.stdout.strip() == "ran", out.stderr
    tied = lifeline.tied_env({"A": "1"})
    assert tied == {"A": "1", lifeline.PARENT_ENV: str(os.getpid())}
