"""The launcher's run context: every resource is released in one order however the run ends."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from harness.autopilot import sitl
from harness.core.errors import ScenarioError
from harness.net.model import NetworkKind
from harness.record.sink import WorldTee
from harness.run import launcher as launcher_module
from harness.run.children import Children
from harness.run.launcher import Launcher
from harness.run.ports import PortBlock
from harness.run.result import RunStatus
from harness.scenario.plan import LaunchPlan

pytestmark = pytest.mark.sim

RELEASE_ORDER = ["channel", "mavlink", "world", "settle", "children", "ports"]
"""The channel first (every peer told), the MAVLink thread before the recorders close, the missions' own ends
before their processes are stopped, the port block last (``Launcher._open``)."""


def _record_releases(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    order: list[str] = []

    def wrap(owner: object, name: str, label: str) -> None:
        original = getattr(owner, name)

        def recorded(*args: object, **kwargs: object) -> object:
            order.append(label)
            return original(*args, **kwargs)

        monkeypatch.setattr(owner, name, recorded)

    wrap(launcher_module.Channel, "close", "channel")
    wrap(sitl, "close_mavlink", "mavlink")
    wrap(WorldTee, "close", "world")
    wrap(launcher_module, "settle", "settle")
    wrap(Children, "stop", "children")
    wrap(PortBlock, "__exit__", "ports")
    return order


def _plan(out: Path) -> LaunchPlan:
    # one in-process vehicle and a network process: a child to stop, the MAVLink side of this process to close
    return LaunchPlan(vehicles=1, out=out, network=NetworkKind.BUILTIN, duration_s=1.0, workers=1)


def test_ctrl_c_in_the_tick_loop_releases_everything_in_order_and_writes_the_summary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    order = _record_releases(monkeypatch)
    stopped: list[Children] = []
    stop = Children.stop

    def keep(self: Children) -> None:
        stopped.append(self)
        stop(self)

    monkeypatch.setattr(Children, "stop", keep)

    def interrupted(self: Launcher, run: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(Launcher, "_loop", interrupted)
    result = Launcher(_plan(tmp_path)).run()
    assert result.status == RunStatus.INTERRUPTED
    assert order == RELEASE_ORDER
    assert json.loads((tmp_path / "summary.json").read_text())["status"] == "interrupted"
    (children,) = stopped
    assert list(children.procs) == ["network"] and children.procs["network"].poll() is not None


def test_a_vehicle_port_taken_at_start_is_one_line_and_releases_what_was_built(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    order = _record_releases(monkeypatch)

    def taken(*args: object, **kwargs: object) -> object:
        raise ScenarioError("udp port 14540 is in use by another program")

    monkeypatch.setattr(sitl, "attach_mavlink", taken)
    result = Launcher(_plan(tmp_path)).run()
    assert (result.status, result.message) == (RunStatus.FAILED, "udp port 14540 is in use by another program")
    assert order == RELEASE_ORDER
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["message"] == result.message


def test_a_finished_run_releases_everything_in_the_same_order(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    order = _record_releases(monkeypatch)
    result = Launcher(_plan(tmp_path)).run()
    assert result.status == RunStatus.OK and result.sim_time_s == pytest.approx(1.0)
    assert order == RELEASE_ORDER


def test_a_resource_that_fails_to_close_still_releases_the_rest_and_writes_the_summary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A closer that raises (a bug in one vehicle's MAVLink side, say): every other resource is released all the
    same, no process is left, and the run ends failed with a summary that says why (before: no summary at all)."""
    order = _record_releases(monkeypatch)
    close = sitl.close_mavlink
    stopped: list[Children] = []
    stop = Children.stop

    def failing_close(*args: object, **kwargs: object) -> None:
        close(*args, **kwargs)  # type: ignore[arg-type]
        raise RuntimeError("the MAVLink side could not close")

    def stop_and_keep(self: Children, *args: object, **kwargs: object) -> object:
        stopped.append(self)
        return stop(self, *args, **kwargs)

    monkeypatch.setattr(sitl, "close_mavlink", failing_close)
    monkeypatch.setattr(Children, "stop", stop_and_keep)
    result = Launcher(_plan(tmp_path)).run()
    assert result.status == RunStatus.FAILED and "could not close" in result.message
    assert order == RELEASE_ORDER  # the failing closer ran, and everything after it too
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["status"] == "failed" and "could not close" in summary["message"]
    assert stopped and all(p.poll() is not None for c in stopped for p in c.procs.values())
