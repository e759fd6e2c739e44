"""The network process's typed configuration: what ``harness run`` writes is what the process reads."""

from __future__ import annotations

from pathlib import Path

import pytest

from harness.core.errors import ScenarioError
from harness.net.model import NetworkKind
from harness.net.process_config import NetworkProcessConfig
from harness.net.subscriber import main


def test_a_configuration_reads_back_as_written_with_its_parameters_typed(tmp_path: Path) -> None:
    cfg = NetworkProcessConfig(
        address="unix://@run", model=NetworkKind.NS3, seed=7, params={"range_m": 250.5, "queue_limit": 3}, run_dir="/r"
    )
    path = tmp_path / "network.json"
    path.write_bytes(cfg.to_json())
    back = NetworkProcessConfig.read(path)
    assert back == cfg and back.model is NetworkKind.NS3 and type(back.params["queue_limit"]) is int


def test_a_file_that_is_not_one_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "network.json"
    path.write_text('{"address": "x", "model": "wifi"}')
    with pytest.raises(ScenarioError, match=r"--config .*network.json: not a network process configuration"):
        NetworkProcessConfig.read(path)
    with pytest.raises(ScenarioError, match="cannot read it"):
        NetworkProcessConfig.read(tmp_path / "missing.json")


def test_the_process_refuses_a_bad_configuration_before_it_connects(tmp_path: Path) -> None:
    path = tmp_path / "network.json"
    path.write_bytes(NetworkProcessConfig(address="unix://@nobody", params={"range_m": "far"}).to_json())
    assert main(["--config", str(path)]) == 2  # the model's own check, one line, no connection tried
    assert main(["--address", "unix://@nobody", "--model", "wifi"]) == 2
