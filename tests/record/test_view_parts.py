"""Pure parts of the 3D view: link quality from network events; the view as an optional extra."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest

from harness import cli
from harness.record import sink, viewer
from harness.record.links import LinkTracker, ratio_color
from harness.record.sample import VehicleSample
from tests.helpers import wait_until

SAMPLE = VehicleSample(
    0, 0, (0.0, 0.0, -1.0), (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 47.0, 8.0, 401.0, (0.0,) * 4, False, False
)


def test_delivery_ratio_per_pair_over_a_sliding_window() -> None:
    lt = LinkTracker(window_s=2.0)
    for k in range(10):  # 0 -> 1: 10 attempts in the first second, 3 dropped
        lt.add({"t_s": 0.1 * k, "kind": "drop" if k in (2, 5, 7) else "deliver", "src": 0, "dst": 1})
    lt.add({"t_s": 0.5, "kind": "deliver", "src": 2, "dst": 1})
    lt.add({"t_s": 0.5, "kind": "drop", "src": 2, "dst": -1, "cause": "no_receiver"})  # ignored
    lt.add({"t_s": 0.5, "kind": "enqueue", "src": 2, "dst": 1})  # ignored
    q = {x.pair: x for x in lt.quality(1.0)}
    assert q[(0, 1)].delivered == 7 and q[(0, 1)].dropped == 3 and q[(0, 1)].ratio == pytest.approx(0.7)
    assert q[(1, 2)].ratio == 1.0
    lt.add({"t_s": 2.9, "kind": "drop", "src": 1, "dst": 0, "cause": "collision"})
    q = {x.pair: x for x in lt.quality(3.0)}  # the first second has left the window
    assert set(q) == {(0, 1)} and q[(0, 1)].ratio == 0.0
    drops = lt.pop_drops(1.0)
    assert [(round(d.t_s, 6), d.src, d.dst) for d in drops] == [(0.2, 0, 1), (0.5, 0, 1), (0.7, 0, 1)]
    assert [d.cause for d in lt.pop_drops(3.0)] == ["collision"] and lt.pop_drops(3.0) == []


def test_ratio_colour_goes_from_red_to_green() -> None:
    r0, r1 = ratio_color(0.0), ratio_color(1.0)
    assert r0[0] > 200 and r0[1] < 50 and r1[1] > 200 and r1[0] < 50
    assert ratio_color(-1.0) == r0 and ratio_color(2.0) == r1


def test_without_rerun_a_run_records_mcap_only_and_harness_view_says_how_to_get_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(sink, "rerun_available", lambda: False)
    monkeypatch.setattr(viewer, "rerun_available", lambda: False)
    world = sink.open_world(tmp_path, 0, 1, (47.0, 8.0, 400.0))
    world.vehicle(SAMPLE)
    world.close()
    assert (tmp_path / "world.mcap").is_file() and not (tmp_path / "world.rrd").exists()
    assert cli.main(["view", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        "harness: harness view needs Rerun, which is not installed: install the view extra: "
        "pip install 'uav-harness[view]' (python3 dev.py demo installs it)"
    )
    assert cli.main(["run", "--vehicles", "1", "--view", "web", "--out", str(tmp_path / "r")]) == 2
    assert "--view web needs Rerun" in capsys.readouterr().err


def test_harness_view_of_a_directory_without_a_recording_is_one_clear_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("rerun")
    assert cli.main(["view", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{tmp_path / 'world.rrd'} does not exist" in err


def test_the_native_viewer_without_a_display_points_to_the_web_viewer(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("rerun")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    (tmp_path / "world.rrd").write_bytes(b"")
    assert cli.main(["view", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "needs a display" in err and "harness view RUNDIR --web" in err


def test_event_lines_are_decoded_in_one_go_and_a_bad_line_is_skipped() -> None:
    lt = LinkTracker(window_s=2.0)
    good = [
        b'{"t_s": 0.5, "kind": "deliver", "src": 0, "dst": 1, "rssi_dbm": -70.1}',
        b'{"t_s": 0.6, "kind": "drop", "src": 1, "dst": 0, "cause": "collision"}',
    ]
    lt.add_lines(good)
    lt.add_lines([*good, b'{"t_s": 0.7, "kind": "deliv', b'{"t_s": 0.8, "kind": "drop", "src": 0, "dst": -1}'])
    (q,) = lt.quality(1.0)
    assert (q.pair, q.delivered, q.dropped) == ((0, 1), 2, 2)
    assert [d.cause for d in lt.pop_drops(1.0)] == ["collision", "collision"]


def test_a_run_stopped_while_the_view_opens_does_not_wait_for_it(tmp_path: Path) -> None:
    """Ctrl-C while Rerun is still being imported (seconds on a loaded machine; `harness run` on main could
    even hang there): the run stops at once with a complete world.mcap, and the view, once it opens after
    all, is closed and its file removed."""
    from harness.record.world import WorldRecorder

    release = threading.Event()
    closed: list[Path] = []

    class LateView:  # the RrdRecorder that the opening thread would return
        path = tmp_path / "world.rrd"

        def close(self) -> None:
            closed.append(self.path)

    def open_late() -> Any:
        release.wait(30)
        LateView.path.write_bytes(b"rrd")
        return LateView()

    opening = sink._Opening(open_late)
    tee = sink.WorldTee(WorldRecorder(tmp_path / "world.mcap", 0, 1), None, opening)
    tee.vehicle(SAMPLE)  # waits in the backlog for the view
    t0 = time.monotonic()
    tee.interrupted()
    tee.close()
    assert time.monotonic() - t0 < 1.0
    assert (tmp_path / "world.mcap").stat().st_size > 0
    release.set()
    wait_until(opening.done, 10.0, "the view to give up opening", poll_s=0.01)
    assert closed == [LateView.path] and not LateView.path.exists()


def test_a_view_that_cannot_write_its_file_is_a_recording_the_run_could_not_complete(tmp_path: Path) -> None:
    """Rerun's file sink stops on a full disk and says so only when flushed: the tee keeps that as a
    recording that could not be completed, naming world.rrd, and world.mcap is finished as usual."""
    from harness.record.world import WorldRecorder, read_topics

    class FullDiskView:
        path = tmp_path / "world.rrd"

        def vehicle(self, s: VehicleSample) -> None:
            pass

        def close(self) -> None:
            raise RuntimeError("File-writer thread shut down prematurely")

    tee = sink.WorldTee(WorldRecorder(tmp_path / "world.mcap", 0, 1), FullDiskView())  # type: ignore[arg-type]
    tee.vehicle(SAMPLE)
    tee.close()
    (err,) = tee.errors
    assert err.path == tmp_path / "world.rrd"
    assert str(err).startswith(
        f"could not write {tmp_path / 'world.rrd'}: the 3D view failed: File-writer thread shut down prematurely ("
    )
    assert read_topics(tmp_path / "world.mcap")["/vehicle/0/pose"]


@pytest.mark.skipif(not sink.rerun_available(), reason="needs Rerun")
def test_a_view_that_cannot_even_create_its_file_is_one_recording_error_not_a_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """CI, 300 kB of tmpfs: the disk was full before Rerun had been imported, so creating world.rrd failed
    (Rerun raises a RuntimeError ending in '(os error 28)'). The run must end on one line naming the file,
    not log a warning with a traceback: here world.rrd is a directory, which fails the same way (os error 21)."""
    (tmp_path / "world.rrd").mkdir()
    world = sink.open_world(tmp_path, 0, 1, (47.0, 8.0, 400.0))
    world.vehicle(SAMPLE)
    world.close()
    (err,) = world.errors
    assert err.path == tmp_path / "world.rrd"
    assert str(err).startswith(f"could not write {tmp_path / 'world.rrd'}: Is a directory"), str(err)
    assert not [r for r in caplog.records if r.levelno >= 30], caplog.text


def test_rust_os_errors_are_read_from_the_text() -> None:
    assert sink.rust_os_error(RuntimeError("Failed to write: No space left on device (os error 28)")) == 28
    assert sink.rust_os_error(RuntimeError("File-writer thread shut down prematurely")) is None


def test_a_web_viewer_port_in_use_is_one_line_before_the_run(tmp_path: Path) -> None:
    import socket

    pytest.importorskip("rerun")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(cli.ScenarioError, match=rf"^--view-port {port}: the port cannot be listened on \("):
            viewer.WebViewer(port)
