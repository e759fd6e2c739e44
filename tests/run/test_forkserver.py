"""The fork server (harness/run/forkserver.py) through ``Children``: real processes forked from it.

Each forked child must look to itself like ``python -m MODULE ARGS`` started with its own environment and
output files, in its own process group; exit codes come back; and nothing outlives the run or the server.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from pathlib import Path

import pytest

from harness.run.children import Children
from tests.run.test_run import pids_with_run_dir

ROOT = Path(__file__).resolve().parents[2]
CHILD = "tests.run.forked_child"


def _env(run_dir: Path, tag: str) -> dict[str, str]:
    return {"PYTHONPATH": str(ROOT), "FORKED_TEST": tag, "HARNESS_RUN_DIR": str(run_dir), "PATH": os.environ["PATH"]}


def _argv(*args: str) -> list[str]:
    return [sys.executable, "-m", CHILD, *args]


def test_forked_children_run_as_python_dash_m_with_their_own_env_files_and_group(tmp_path: Path) -> None:
    with Children(tmp_path, fork_preload=(CHILD,)) as sup:
        a = sup.start("a", _argv("0"), _env(tmp_path, "first") | {"EXTRA": "1"}, forked=True)
        b = sup.start("b", _argv("3", "0.2"), _env(tmp_path, "second"), forked=True)
        assert a.wait(30) == 0 and b.wait(30) == 3
        assert "forkserver" in sup.procs and sup.procs["forkserver"].poll() is None  # one server for both
        exits = dict(sup.poll_exits())
        assert exits["a"] == 0 and exits["b"] == 3
    seen = [json.loads((tmp_path / f"{n}.stdout").read_text()) for n in ("a", "b")]
    assert [s["argv"] for s in seen] == [["0"], ["3", "0.2"]]
    assert [s["env"] for s in seen] == ["first", "second"]
    assert [s["extra"] for s in seen] == ["1", None], "each child has its own environment, not the first one's"
    assert all(s["main"] == "__main__" and s["cwd"] == os.getcwd() for s in seen)
    assert all(s["pgid"] == s["pid"] for s in seen), "each child leads its own process group"
    assert seen[0]["pid"] != seen[1]["pid"] and os.getpid() not in (seen[0]["pid"], seen[1]["pid"])
    assert (tmp_path / "b.stderr").read_text() == "to stderr\n"
    assert not pids_with_run_dir(tmp_path), "the server ended with the run"


def test_an_optional_preload_is_imported_where_installed_and_skipped_where_not(tmp_path: Path) -> None:
    """``fork_preload`` names ending in ``?`` (MAVSDK for missions): imported once by the server when installed,
    and a missing one does not keep the server from starting."""
    with Children(tmp_path, fork_preload=(CHILD, "wave?", "no_such_module_here?")) as sup:
        assert sup.start("a", _argv("0"), _env(tmp_path, "first"), forked=True).wait(30) == 0
    assert json.loads((tmp_path / "a.stdout").read_text())["wave"] is True


def test_stop_ends_a_forked_child_that_still_runs(tmp_path: Path) -> None:
    sup = Children(tmp_path, grace_s=1.0, fork_preload=(CHILD,))
    slow = sup.start("slow", _argv("0", "60"), _env(tmp_path, "x"), forked=True)
    out = tmp_path / "slow.stdout"
    deadline = time.monotonic() + 30
    while not (out.is_file() and out.read_text()) and time.monotonic() < deadline:
        time.sleep(0.05)
    pid = json.loads(out.read_text())["pid"]
    assert slow.pid == pid and slow.poll() is None
    start = time.monotonic()
    sup.stop()
    assert time.monotonic() - start < 5.0
    assert slow.poll() == -signal.SIGTERM
    assert not pids_with_run_dir(tmp_path)


def test_a_killed_fork_server_takes_its_children(tmp_path: Path) -> None:
    with Children(tmp_path, fork_preload=(CHILD,)) as sup:
        slow = sup.start("slow", _argv("0", "60"), _env(tmp_path, "x"), forked=True)
        deadline = time.monotonic() + 30
        while slow.pid is None and time.monotonic() < deadline:
            time.sleep(0.05)
        pid = slow.pid
        assert pid is not None
        server = sup.procs["forkserver"]
        assert server.pid is not None
        os.kill(server.pid, signal.SIGKILL)
        assert slow.wait(10) == -signal.SIGKILL
        deadline = time.monotonic() + 5
        while pids_with_run_dir(tmp_path) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not pids_with_run_dir(tmp_path), "the server's child outlived it"


def test_a_child_that_exits_before_the_run_starts_fails_it_at_once(tmp_path: Path) -> None:
    from harness.core.errors import SimulationError
    from harness.run.launcher import _all_joined

    with Children(tmp_path) as sup:
        sup.start("network", [sys.executable, "-c", "raise SystemExit(3)"], _env(tmp_path, "x"))
        deadline = time.monotonic() + 30
        with pytest.raises(SimulationError, match=r"the network process exited with 3 before the run started"):
            while time.monotonic() < deadline:
                assert not _all_joined([], 1, sup)
                time.sleep(0.02)
        assert time.monotonic() < deadline, "the exit was never noticed"
