"""One data path for the run's ground truth: the launcher writes to a ``WorldSink``; ``open_world`` gives it
``world.mcap`` and, when Rerun is installed, ``world.rrd`` (the 3D view) fed by the same calls.

The view is an extra: if Rerun is missing, ``world.rrd`` is simply not written; if it fails during a run,
it is switched off with a warning and the run (and ``world.mcap``) goes on.
"""

from __future__ import annotations

import importlib.util
import logging
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from harness.record.world import WorldRecorder

if TYPE_CHECKING:
    from harness.autopilot.api import AutopilotApi
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

    def vehicle(
        self,
        t_ns: int,
        vehicle: int,
        pos_ned_m: tuple[float, float, float],
        quat_wxyz: tuple[float, float, float, float],
        vel_ned_m_s: tuple[float, float, float],
        lat_deg: float,
        lon_deg: float,
        alt_amsl_m: float,
        motors: tuple[float, ...],
        on_ground: bool,
        crashed: bool,
    ) -> None: ...

    def tick(self, t_ns: int, tick: int, wall_s: float, tick_wall_us: float) -> None: ...

    def event(self, t_ns: int, kind: str, detail: dict[str, Any]) -> None: ...

    def flush(self) -> None: ...

    def close(self) -> None: ...


class WorldTee:
    """``world.mcap`` always; the 3D view (``world.rrd``, live viewers) when there is one."""

    def __init__(self, mcap: WorldRecorder, view: RrdRecorder | None) -> None:
        self.mcap = mcap
        self.view = view

    def _guard(self, call: Callable[[RrdRecorder], None]) -> None:
        if self.view is None:
            return
        try:
            call(self.view)
        except Exception:
            log.warning("the 3D view failed and is switched off for the rest of the run", exc_info=True)
            view, self.view = self.view, None
            try:
                view.close()
            except Exception:
                pass

    def vehicle(
        self,
        t_ns: int,
        vehicle: int,
        pos_ned_m: tuple[float, float, float],
        quat_wxyz: tuple[float, float, float, float],
        vel_ned_m_s: tuple[float, float, float],
        lat_deg: float,
        lon_deg: float,
        alt_amsl_m: float,
        motors: tuple[float, ...],
        on_ground: bool,
        crashed: bool,
    ) -> None:
        args = (t_ns, vehicle, pos_ned_m, quat_wxyz, vel_ned_m_s, lat_deg, lon_deg, alt_amsl_m, motors, on_ground)
        self.mcap.vehicle(*args, crashed)
        if self.view is not None:
            self._guard(lambda v: v.vehicle(*args, crashed))

    def tick(self, t_ns: int, tick: int, wall_s: float, tick_wall_us: float) -> None:
        self.mcap.tick(t_ns, tick, wall_s, tick_wall_us)
        if self.view is not None:
            self._guard(lambda v: v.tick(t_ns, tick, wall_s, tick_wall_us))

    def event(self, t_ns: int, kind: str, detail: dict[str, Any]) -> None:
        self.mcap.event(t_ns, kind, detail)
        self._guard(lambda v: v.event(t_ns, kind, detail))

    def attach_autopilots(self, aps: Mapping[int, AutopilotApi]) -> None:
        self._guard(lambda v: v.attach_autopilots(aps))

    def flush(self) -> None:
        self.mcap.flush()
        self._guard(lambda v: v.flush())

    def close(self) -> None:
        try:
            self.mcap.close()
        finally:
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
    """
    mcap = WorldRecorder(out / "world.mcap", epoch_ns, n_vehicles)
    view: RrdRecorder | None = None
    if rrd_wanted(serve_port):
        from harness.record.rrd import RrdRecorder

        try:
            view = RrdRecorder(
                out / "world.rrd",
                n_vehicles,
                origin,
                serve_port=serve_port,
                min_wall_s=0.1 if serve_port is not None else 0.5,
                events_path=out / "network-events.jsonl",
            )
        except Exception:
            log.warning("world.rrd (the 3D view) could not be opened; the run goes on without it", exc_info=True)
    elif serve_port is not None:
        log.warning("no live view: %s", INSTALL_HINT)
    return WorldTee(mcap, view)
