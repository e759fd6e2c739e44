"""The root's ledger of every vehicle's ground truth, tick by tick, whichever process simulated it.

``harness run`` records the truth of its own share at each tick, but an autopilot host that steps its
vehicles' physics reports only at the ticks with phases, with every tick since its last report
(:func:`harness.wire.protocol.unpack_ticks`). A tick is recorded once every vehicle's truth at it is
known, in tick order, so the recording and the summaries are the same with 1 or N workers.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from harness.core.errors import SimulationError
from harness.wire import protocol as p


@dataclass
class Row:
    """One tick: each vehicle's truth (``None`` until known), motor commands and autopilot status."""

    tick: int
    t_ns: int
    wall_s: float
    """Wall time of the run when this process stepped the tick (for ``/sim/tick``)."""
    tick_us: float
    truth: list[Any]
    motors: list[tuple[float, ...]]
    status: list[int]
    missing: int = field(init=False)

    def __post_init__(self) -> None:
        self.missing = self.truth.count(None)


class Ledger:
    """Ticks not yet known for every vehicle, oldest first (at most one phase period of them)."""

    def __init__(self, vehicles: int) -> None:
        self.n = vehicles
        self._rows: deque[Row] = deque()

    def open(self, row: Row) -> None:
        if len(row.truth) != self.n:
            raise ValueError(f"a row of {len(row.truth)} vehicles, the run has {self.n}")
        rows = self._rows
        if rows and row.tick != rows[-1].tick + 1:
            raise ValueError(f"tick {row.tick} opened after tick {rows[-1].tick}: the rows are consecutive ticks")
        rows.append(row)

    def reported(self, vehicle: int, tick: int, reports: Sequence[p.TickReport]) -> None:
        """A host's reports for ``vehicle``: the ticks up to ``tick``, the last at ``tick``."""
        rows = self._rows
        first = tick - len(reports) + 1
        base = rows[0].tick if rows else first  # the rows are consecutive ticks: row k is at k - base
        for k, rep in enumerate(reports, start=first):
            i = k - base
            row = rows[i] if 0 <= i < len(rows) else None
            if row is not None and row.tick != k:
                row = None
            if row is None or row.truth[vehicle] is not None:
                raise SimulationError(
                    f"the autopilot host of vehicle {vehicle} reported tick {k}, which "
                    + ("it had already reported" if row is not None else "this run did not step")
                )
            row.truth[vehicle], row.motors[vehicle], row.status[vehicle] = rep
            row.missing -= 1

    def complete(self) -> Iterator[Row]:
        """Pop the oldest rows while every vehicle's truth is in them."""
        rows = self._rows
        while rows and rows[0].missing == 0:
            yield rows.popleft()

    def check_through(self, tick: int) -> None:
        """After a phase tick every host has reported: a vehicle still missing at or before it never will be."""
        for row in self._rows:
            if row.tick <= tick:
                lost = [v for v, t in enumerate(row.truth) if t is None]
                raise SimulationError(
                    f"no ground truth for vehicles {lost} at tick {row.tick} from their autopilot host"
                )
