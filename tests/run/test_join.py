"""``harness join``'s own resources: the channel it joined with is stopped however the join ends."""

from __future__ import annotations

from pathlib import Path

import pytest

from harness.channel import Channel, ChannelConfig
from harness.core.clock import Clock
from harness.core.errors import ScenarioError
from harness.run import join
from harness.run.join import JoinPlan, run_join


def test_the_joined_channel_stops_when_the_ports_cannot_be_had(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A failure before the run's block (no port block free) still stops the channel that joined the root: its
    thread ends and the root sees the child go (before: it ran on, a daemon thread holding the connection)."""
    started: list[Channel] = []

    def connect(plan: JoinPlan, clock: Clock) -> Channel:
        channel = Channel(ChannelConfig(name="child")).start()  # the joined channel, without a root to join
        started.append(channel)
        return channel

    def no_ports(*_args: object, **_kwargs: object) -> object:
        raise ScenarioError("no free block of ports")

    monkeypatch.setattr(join, "_connect", connect)
    monkeypatch.setattr(join, "allocate", no_ports)
    with pytest.raises(ScenarioError, match="no free block"):
        run_join(JoinPlan(parent="tcp://127.0.0.1:1", first_vehicle=0, vehicles=1, out=tmp_path))
    assert len(started) == 1 and started[0].wait(5.0)
