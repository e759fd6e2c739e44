"""The root's side of the tree across machines, as pure logic: the secret, when a run is done, remote summaries."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pytest

from harness.channel import MissionExit
from harness.core.errors import ScenarioError
from harness.run.result import VehicleSummary
from harness.run.tree import fill_remote, missions_done, read_secret, secret_env


def test_secret_from_file_then_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HARNESS_CHANNEL_SECRET", "from-env")
    path = tmp_path / "secret"
    path.write_text("from-file\nignored\n")
    assert read_secret(str(path)) == b"from-file"
    assert read_secret(None) == b"from-env"
    monkeypatch.delenv("HARNESS_CHANNEL_SECRET")
    assert read_secret(None) is None
    path.write_text("\n")
    with pytest.raises(ScenarioError, match="the file is empty"):
        read_secret(str(path))
    with pytest.raises(ScenarioError, match="missing: the file does not exist"):
        read_secret(str(tmp_path / "missing"))
    assert secret_env({"A": "1"}, b"s") == {"A": "1", "HARNESS_CHANNEL_SECRET": "s"}
    assert secret_env({"A": "1"}, None) == {"A": "1"}


@dataclass
class _Channel:
    mission_exits: list[MissionExit] = field(default_factory=list)
    running_below: int = 0

    def missions_below(self) -> int:
        return self.running_below


def test_run_is_done_when_its_own_and_its_childrens_missions_are() -> None:
    ch = _Channel()
    assert not missions_done(ch, 0, 2)  # nothing ever ran: only the duration ends it
    ch.mission_exits.append(MissionExit("m", 2, 0, ""))  # a remote mission (vehicle 2 of a 2-local run)
    ch.running_below = 1
    assert not missions_done(ch, 1, 2)  # vehicle 0's own mission still runs, and one remote
    ch.mission_exits.append(MissionExit("m", 0, 0, ""))
    assert not missions_done(ch, 1, 2)  # the child still announces a running mission
    ch.running_below = 0
    assert missions_done(ch, 1, 2)
    swarm = _Channel([MissionExit("swarm:f.py", -1, 0, "")])
    assert missions_done(swarm, 1, 2)  # a swarm mission counts as the root's own


def test_remote_vehicles_get_their_childrens_mission_exits() -> None:
    summaries = [VehicleSummary(i, None) for i in range(3)]
    fill_remote(summaries, [MissionExit("mission:x.py:2", 2, 3, "exited"), MissionExit("a", 0, 0, "")], 1)
    assert (summaries[2].mission, summaries[2].mission_exit_code) == ("mission:x.py:2", 3)
    assert summaries[0].mission is None and summaries[1].mission is None  # local ones are the launcher's
