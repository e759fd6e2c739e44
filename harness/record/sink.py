"""One data path for the run's ground truth: the launcher writes to a ``WorldSink``; ``open_world`` gives it
``world.mcap`` and, when Rerun is installed, ``world.rrd`` (the 3D view) fed by the same calls.

The view is an extra: if Rerun is missing, ``world.rrd`` is simply not written; if it fails during a run,
it is switched off with a warning and the run (and ``world.mcap``) goes on.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import threading
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from harness.record.sample import VehicleSample
from harness.record.world import WorldRecorder

if TYPE_CHECKING:
    from harness.autopilot.services import System
    from harness.record.rrd import RrdRecorder

log = logging.getLogger(__name__)

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

    def flush(self) -> None: ...

    def close(self) -> None: ...


class _Opening:
    """Opens the view on a thread: importing Rerun (pyarrow included) takes ~0.5 s of CPU, which a run
    spends while its processes start instead of before."""

    def __init__(self, open_view: Callable[[], RrdRecorder | None]) -> None:
        self.view: RrdRecorder | None = None
        self._open = open_view
        self._given_up = threading.Event()
        self._thread = threading.Thread(target=self._run, name="open-world.rrd", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        view = self._open()
        if view is not None and self._given_up.is_set():  # the run ended while Rerun was being imported
            view.close()
            view.path.unlink(missing_ok=True)
            view = None
        self.view = view

    def give_up(self) -> None:
        """Nobody will wait for the view: it is closed and removed if it opens after all."""
        self._given_up.set()

    def done(self) -> bool:
        return not self._thread.is_alive()

    def wait(self) -> RrdRecorder | None:
        self._thread.join()
        return self.view


class WorldTee:
    """``world.mcap`` always; the 3D view (``world.rrd``, live viewers) when there is one.

    While the view is still being opened (``opening``), its calls wait in a backlog and are replayed in
    order once it is open, so ``world.rrd`` holds the whole run.
    """

    def __init__(self, mcap: WorldRecorder, view: RrdRecorder | None, opening: _Opening | None = None) -> None:
        self.mcap = mcap
        self.view = view
        self._opening = opening
        self._backlog: list[Callable[[RrdRecorder], None]] = []

    def _guard(self, call: Callable[[RrdRecorder], None]) -> None:
        if self._opening is not None:
            if not self._opening.done():
                self._backlog.append(call)
                return
            self._opened(self._opening.wait())
        self._apply(call)

    def _opened(self, view: RrdRecorder | None) -> None:
        self._opening = None
        self.view = view
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
        log.warning("the 3D view failed and is switched off for the rest of the run", exc_info=True)
        view, self.view = self.view, None
        if view is not None:
            try:
                view.close()
            except Exception:
                pass

    def vehicle(self, s: VehicleSample) -> None:
        self.mcap.vehicle(s)
        if self.view is not None or self._opening is not None:
            self._guard(lambda v: v.vehicle(s))

    def tick(self, t_ns: int, tick: int, wall_s: float, tick_wall_us: float) -> None:
        self.mcap.tick(t_ns, tick, wall_s, tick_wall_us)
        if self.view is not None or self._opening is not None:
            self._guard(lambda v: v.tick(t_ns, tick, wall_s, tick_wall_us))

    def event(self, t_ns: int, kind: str, detail: dict[str, Any]) -> None:
        self.mcap.event(t_ns, kind, detail)
        self._guard(lambda v: v.event(t_ns, kind, detail))

    def attach_autopilots(self, aps: Mapping[int, System]) -> None:
        self._guard(lambda v: v.attach_autopilots(aps))

    def flush(self) -> None:
        self.mcap.flush()
        self._guard(lambda v: v.flush())

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
        try:
            self.mcap.close()
        finally:
            if self._opening is not None:
                self._opened(self._opening.wait())
            self._guard(lambda v: v.close())
            self.view = None


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

    def open_view() -> RrdRecorder | None:
        try:
            from harness.record.rrd import RrdRecorder

            return RrdRecorder(
                out / "world.rrd",
                n_vehicles,
                origin,
                serve_port=serve_port,
                # live: a batch per 0.5 s of sim (1 s at 50 vehicles; at most 10 per wall second); file only:
                # per 2 s of sim (at most 2 per wall second)
                batch_s=0.5 * max(1.0, n_vehicles / 25) if serve_port is not None else 2.0,
                min_wall_s=0.1 if serve_port is not None else 0.5,
                events_path=out / "network-events.jsonl",
            )
        except Exception:
            log.warning("world.rrd (the 3D view) could not be opened; the run goes on without it", exc_info=True)
            return None

    if serve_port is not None:
        return WorldTee(mcap, open_view())
    return WorldTee(mcap, None, _Opening(open_view))
