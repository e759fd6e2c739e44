"""One data path for the run's ground truth: the launcher writes to a ``WorldSink``; ``open_world`` gives it
``world.mcap`` and, when Rerun is installed, ``world.rrd`` (the 3D view) fed by the same calls.

The view is an extra: if Rerun is missing, ``world.rrd`` is simply not written. A recording that cannot be
completed — ``world.mcap`` or ``world.rrd`` on a full disk, a view that fails — is in ``WorldTee.errors``
(``world.mcap``'s failure also raised, so that the run stops at once): the run fails and names the file.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import re
import sys
import threading
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn, Protocol

from harness.autopilot.camera import Capture
from harness.core.files import RecordingError
from harness.record.sample import VehicleSample, WorldEvent, capture_detail
from harness.record.world import WorldRecorder

if TYPE_CHECKING:
    from harness.autopilot.services import System
    from harness.record.rrd import RrdRecorder

log = logging.getLogger(__name__)

QUIET_RERUN_LOG = "warn,re_log_encoding::rrd=off,re_sdk::recording_stream=off,re_sdk::log_sink=off"
"""``RUST_LOG`` for a run (unless set): Rerun's own error lines about ``world.rrd`` are left out, because the
run reports a recording it could not complete itself, in one line that names the file."""

INSTALL_HINT = "install the view extra: pip install 'uav-harness[view]' (python3 dev.py demo installs it)"


def rerun_available() -> bool:
    return importlib.util.find_spec("rerun") is not None


def rrd_wanted(serve_port: int | None) -> bool:
    """``world.rrd`` is written whenever Rerun is installed, unless ``HARNESS_RRD=0`` (benchmarks, big sweeps)
    and no live view was asked for."""
    return rerun_available() and (serve_port is not None or os.environ.get("HARNESS_RRD", "1") != "0")


class WorldSink(Protocol):
    """What the physics loop records: every vehicle's truth at the record rate, tick timing, events."""

    def vehicle(self, s: VehicleSample) -> None: ...

    def tick(self, t_ns: int, tick: int, wall_s: float, tick_wall_us: float) -> None: ...

    def event(self, t_ns: int, kind: str, detail: dict[str, Any]) -> None: ...

    def capture(self, vehicle: int, c: Capture) -> None:
        """A picture vehicle ``vehicle``'s camera took (``/sim/events`` kind ``capture``; the view's capture points)."""
        ...

    def flush(self) -> None: ...

    def close(self) -> None: ...


class _Opening:
    """Opens the view on a thread: importing Rerun (pyarrow included) takes ~0.5 s of CPU, which a run
    spends while its processes start instead of before."""

    def __init__(self, open_view: Callable[[], RrdRecorder | RecordingError | None]) -> None:
        self.view: RrdRecorder | RecordingError | None = None
        self._open = open_view
        self._given_up = threading.Event()
        self._thread = threading.Thread(target=self._run, name="open-world.rrd", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        view = self._open()
        if view is not None and not isinstance(view, RecordingError) and self._given_up.is_set():
            # the run ended while Rerun was being imported
            view.close()
            view.path.unlink(missing_ok=True)
            view = None
        self.view = view

    def give_up(self) -> None:
        """Nobody will wait for the view: it is closed and removed if it opens after all."""
        self._given_up.set()

    def done(self) -> bool:
        return not self._thread.is_alive()

    def wait(self) -> RrdRecorder | RecordingError | None:
        self._thread.join()
        return self.view


class WorldTee:
    """``world.mcap`` always; the 3D view (``world.rrd``, live viewers) when there is one.

    While the view is still being opened (``opening``), its calls wait in a backlog and are replayed in
    order once it is open, so ``world.rrd`` holds the whole run.
    """

    def __init__(
        self, mcap: WorldRecorder, view: RrdRecorder | RecordingError | None, opening: _Opening | None = None
    ) -> None:
        self.mcap = mcap
        self.view: RrdRecorder | None = None
        self._opening = opening
        self._backlog: list[Callable[[RrdRecorder], None]] = []
        self.errors: list[RecordingError] = []
        """The recordings that could not be completed (a full disk, a view that failed), first first."""
        self._set_view(view)

    def _set_view(self, view: RrdRecorder | RecordingError | None) -> None:
        if isinstance(view, RecordingError):  # world.rrd could not even be created (a full or read-only disk)
            self.errors.append(view)
            view = None
        self.view = view

    def _mcap_failed(self, exc: OSError) -> NoReturn:
        """``world.mcap`` could not be written: it keeps what it holds (a valid file), the run must stop."""
        self.mcap.abandon()
        err = RecordingError.of(self.mcap.path, exc)
        self.errors.append(err)
        raise err

    def _guard(self, call: Callable[[RrdRecorder], None]) -> None:
        if self._opening is not None:
            if not self._opening.done():
                self._backlog.append(call)
                return
            self._opened(self._opening.wait())
        self._apply(call)

    def _opened(self, view: RrdRecorder | RecordingError | None) -> None:
        self._opening = None
        self._set_view(view)
        backlog, self._backlog = self._backlog, []
        for call in backlog:
            self._apply(call)

    def _apply(self, call: Callable[[RrdRecorder], None]) -> None:
        """``call`` on the view, if there is one; a failure switches the view off."""
        if self.view is None:
            return
        try:
            call(self.view)
        except Exception:
            self._fail()

    def _fail(self) -> None:
        view, self.view = self.view, None
        if view is None:
            return
        exc = sys.exc_info()[1]
        log.debug("the 3D view failed", exc_info=True)
        if isinstance(exc, OSError):
            self.errors.append(RecordingError.of(view.path, exc))
        else:
            self.errors.append(RecordingError.writer_stopped(view.path, f"the 3D view failed: {exc}"))
        try:
            view.close()
        except Exception:
            pass

    def vehicle(self, s: VehicleSample) -> None:
        try:
            self.mcap.vehicle(s)
        except OSError as exc:
            self._mcap_failed(exc)
        if self._opening is not None:
            self._guard(lambda v: v.vehicle(s))
        elif self.view is not None:  # what _apply does, without a closure per vehicle and sample
            try:
                self.view.vehicle(s)
            except Exception:
                self._fail()

    def tick(self, t_ns: int, tick: int, wall_s: float, tick_wall_us: float) -> None:
        try:
            self.mcap.tick(t_ns, tick, wall_s, tick_wall_us)
        except OSError as exc:
            self._mcap_failed(exc)
        if self._opening is not None:
            self._guard(lambda v: v.tick(t_ns, tick, wall_s, tick_wall_us))
        elif self.view is not None:
            try:
                self.view.tick(t_ns, tick, wall_s, tick_wall_us)
            except Exception:
                self._fail()

    def event(self, t_ns: int, kind: str, detail: dict[str, Any]) -> None:
        try:
            self.mcap.event(t_ns, kind, detail)
        except OSError as exc:
            self._mcap_failed(exc)
        self._guard(lambda v: v.event(t_ns, kind, detail))

    def capture(self, vehicle: int, c: Capture) -> None:
        self.event(c.t_ns, WorldEvent.CAPTURE, capture_detail(vehicle, c))
        self._guard(lambda v: v.capture(vehicle, c))

    def attach_autopilots(self, aps: Mapping[int, System]) -> None:
        self._guard(lambda v: v.attach_autopilots(aps))

    def flush(self) -> None:
        self.flush_mcap()
        self._guard(lambda v: v.flush())

    def flush_mcap(self) -> None:
        """The chunk in progress of ``world.mcap`` to disk; :class:`RecordingError` when it cannot be written."""
        try:
            self.mcap.flush()
        except OSError as exc:
            self._mcap_failed(exc)

    def interrupted(self) -> None:
        """The run was stopped (Ctrl-C, SIGTERM). A view still being opened is given up, not waited for:
        importing Rerun takes seconds of wall time on a loaded machine, and a run must stop at once (a sweep
        kills a run that has not stopped within 3 s). ``world.mcap`` is complete; ``world.rrd`` is not written."""
        if self._opening is None or self._opening.done():
            return
        self._opening.give_up()
        if not self._opening.done():  # (done after all: close() replays the backlog as usual)
            log.warning("the run was stopped while world.rrd was being opened: no world.rrd for this run")
            self._opening = None
            self._backlog = []

    def close(self) -> None:
        """Finish both files; what could not be completed is in :attr:`errors` (never raised: the run is ending)."""
        try:
            self.mcap.close()
        except OSError as exc:
            self.mcap.abandon()
            self.errors.append(RecordingError.of(self.mcap.path, exc))
        if self._opening is not None:
            self._opened(self._opening.wait())
        self._guard(lambda v: v.close())
        self.view = None


def rust_os_error(exc: BaseException) -> int | None:
    """The errno in a Rust error's text (``... (os error 28)``), or None."""
    m = re.search(r"\(os error (\d+)\)", str(exc))
    return int(m.group(1)) if m else None


def open_world(
    out: Path,
    epoch_ns: int,
    n_vehicles: int,
    origin: tuple[float, float, float],
    *,
    serve_port: int | None = None,
) -> WorldTee:
    """``out/world.mcap``, plus ``out/world.rrd`` when Rerun is installed (served live on ``serve_port``).

    The environment variable ``HARNESS_RRD=0`` leaves ``world.rrd`` out (unless a live view is asked for).
    A live view is open when this returns; a file-only one opens on a thread (see ``_Opening``).
    """
    mcap = WorldRecorder(out / "world.mcap", epoch_ns, n_vehicles)
    if not rrd_wanted(serve_port):
        if serve_port is not None:
            log.warning("no live view: %s", INSTALL_HINT)
        return WorldTee(mcap, None)

    def open_view() -> RrdRecorder | RecordingError | None:
        path = out / "world.rrd"
        try:
            from harness.record.rrd import RrdRecorder

            return RrdRecorder(
                path,
                n_vehicles,
                origin,
                serve_port=serve_port,
                # live: a batch per 0.5 s of sim (1 s at 50 vehicles; at most 10 per wall second); file only:
                # per 2 s of sim (at most 2 per wall second)
                batch_s=0.5 * max(1.0, n_vehicles / 25) if serve_port is not None else 2.0,
                min_wall_s=0.1 if serve_port is not None else 0.5,
                events_path=out / "network-events.jsonl",
            )
        except OSError as exc:
            return RecordingError.of(path, exc)
        except Exception as exc:
            log.debug("world.rrd could not be opened", exc_info=True)
            os_errno = rust_os_error(exc)
            if os_errno is not None:  # Rerun's file sink wraps the OS error in a RuntimeError's text
                return RecordingError.of(path, OSError(os_errno, os.strerror(os_errno)))
            log.warning("world.rrd (the 3D view) could not be opened (%s); the run goes on without it", exc)
            return None

    if serve_port is not None:
        return WorldTee(mcap, open_view())
    return WorldTee(mcap, None, _Opening(open_view))
