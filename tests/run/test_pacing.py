"""``--speed`` as a rate (``harness.run.pacing``) and missions' ends as they were (``harness.run.exits``)."""

from __future__ import annotations

import subprocess
from dataclasses import dataclass

import pytest

from harness.channel import MissionExit
from harness.core.clock import NS_PER_S
from harness.run.exits import settle, status_text
from harness.run.pacing import MAX_LAG_NS, Pacer

MS = NS_PER_S // 1000


def test_pacing_waits_for_the_schedule_and_makes_up_a_short_lag() -> None:
    pacer = Pacer(2.0, start_ns=1000 * MS)
    assert pacer.wait_ns(0, 1000 * MS) == 0
    assert pacer.wait_ns(1 * NS_PER_S, 1000 * MS) == 500 * MS  # 1 s of sim is due 0.5 s of wall later at x2
    assert pacer.wait_ns(2 * NS_PER_S, 2300 * MS) == 0  # 300 ms late: made up by running faster
    assert pacer.moved_ns == 0
    assert pacer.wait_ns(2 * NS_PER_S + 200 * MS, 2300 * MS) == 0  # still due earlier than now


def test_after_a_stall_the_schedule_moves_and_the_rate_stays() -> None:
    pacer = Pacer(2.0, start_ns=0)
    assert pacer.wait_ns(10 * NS_PER_S, 25 * NS_PER_S) == 0  # 20 s behind (due at 5 s)
    assert pacer.moved_ns == 20 * NS_PER_S - MAX_LAG_NS
    # from here on: 1 s of sim per 0.5 s of wall, after at most MAX_LAG_NS made up
    late = pacer.wait_ns(11 * NS_PER_S, 25 * NS_PER_S)
    assert late == 0
    assert pacer.wait_ns(12 * NS_PER_S, 25 * NS_PER_S) == NS_PER_S - MAX_LAG_NS
    assert pacer.wait_ns(14 * NS_PER_S, 26 * NS_PER_S) == 2 * NS_PER_S - MAX_LAG_NS - NS_PER_S


def test_a_pause_moves_the_schedule_by_its_length() -> None:
    pacer = Pacer(1.0, start_ns=0)
    pacer.shift(5 * NS_PER_S)
    assert pacer.wait_ns(NS_PER_S, 5 * NS_PER_S) == NS_PER_S
    with pytest.raises(ValueError):
        Pacer(0.0, 0)


@dataclass
class _Proc:
    code: int | None

    def wait(self, timeout: float | None = None) -> int:
        if self.code is None:
            raise subprocess.TimeoutExpired("mission", timeout or 0.0)
        return self.code


def test_a_mission_the_channel_lost_gets_its_process_exit_status() -> None:
    exits = [
        MissionExit("m0", 0, -1, "dropped: disconnected"),
        MissionExit("m1", 1, -1, "dropped: connection broke: [Errno 104] Connection reset by peer"),
        MissionExit("m2", 2, -1, "dropped: disconnected"),  # its process runs on
        MissionExit("m3", 3, -1, "dropped: stalled: no END-TICK-0 within 10 s"),  # dropped by the channel: stays
        MissionExit("m4", 4, 3, "script exited with 3"),
    ]
    procs = {f"mission-{i}": _Proc(c) for i, c in enumerate((0, -9, None, -15, 3))}
    settled = settle(exits, procs, lambda v: f"mission-{v}", wait_s=0.0)
    assert settled == ["m0", "m1"]
    assert [(e.exit_code, e.reason) for e in exits] == [
        (0, "exited with 0, without a goodbye to the channel"),
        (-9, "killed by SIGKILL"),
        (-1, "dropped: disconnected"),
        (-1, "dropped: stalled: no END-TICK-0 within 10 s"),
        (3, "script exited with 3"),
    ]
    assert status_text(-15) == "killed by SIGTERM" and status_text(-99) == "killed by signal 99"
