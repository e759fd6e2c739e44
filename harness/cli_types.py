"""Argument types of the ``harness`` command: each value checked as it is parsed, one error line naming the option.

``OneLineParser`` prints argparse's errors as one line (``harness run: error: argument --duration: must be a
finite number > 0, got 'nan'``) and exits with status 2, like every other setup error of the command.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from typing import NoReturn

from harness.scenario.limits import MAX_DURATION_S, MAX_RUN_VEHICLES, MAX_WAIT_S, lowest_port


class OneLineParser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: error: {message} (see {self.prog} --help)", file=sys.stderr)
        raise SystemExit(2)


def number(lo: float, hi: float, *, lo_open: bool = False) -> Callable[[str], float]:
    """A finite float within [lo, hi] (or (lo, hi] with ``lo_open``)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value) or value > hi or value < lo or (lo_open and value == lo):
            low = f"> {lo:g}" if lo_open else f">= {lo:g}"
            raise argparse.ArgumentTypeError(f"must be a finite number {low} and <= {hi:g}, got {text!r}")
        return value

    return parse


def integer(lo: int, hi: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer {lo}-{hi}, got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be an integer {lo}-{hi}, got {text!r}")
        return value

    return parse


def port(text: str) -> int:
    """A TCP/UDP port this user may bind (below 1024 only as root)."""
    return integer(lowest_port(), 65535)(text)


def speed(text: str) -> float | None:
    """``max`` (as fast as possible) or a real-time factor."""
    if text == "max":
        return None
    try:
        return number(0.0, 1e6, lo_open=True)(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"must be 'max' or a finite number > 0, got {text!r}") from None


vehicles = integer(1, MAX_RUN_VEHICLES)
"""On one machine at most ``MAX_VEHICLES`` (``check_plan`` says so); a cluster run takes what its workers hold."""
seed = integer(0, 2**63 - 1)
duration = number(0.0, MAX_DURATION_S, lo_open=True)
wait = number(0.0, MAX_WAIT_S, lo_open=True)
sim_time = number(0.0, MAX_DURATION_S)
rate = number(0.0, 100_000.0, lo_open=True)
count = integer(1, 1_000_000)
