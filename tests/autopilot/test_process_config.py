"""The autopilot process's typed configuration: what the launcher writes is what the process reads, the flags
of a hand-started process build the same value, and a file that is not one is one clear line (exit 2)."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from harness.autopilot.firmware import Firmware
from harness.autopilot.process_config import AutopilotProcessConfig
from harness.autopilot.sitl import _config_from_flags, _parser, main
from harness.core.errors import ScenarioError


def test_the_file_round_trips_every_field(tmp_path: Path) -> None:
    cfg = AutopilotProcessConfig(
        address="unix://@run-1",
        vehicles=(2, 3),
        api_port_base=0,
        api_local_port_base=20000,
        gcs_port=14551,
        run_dir=str(tmp_path),
        params={3: {"MPC_XY_CRUISE": 7.5}},
        signing_key_file="/keys/signing.key",
        trust_run=4242,
        firmware=(Firmware.PX4, Firmware.PX4, Firmware.ARDUPILOT, Firmware.PX4),
        tcp_port_base=5760,
        tcp_port_step=10,
        gcs_extra_ports=(14552,),
        tcp_sim_clients=True,
        physics=str(tmp_path / "physics.json"),
        name="autopilot-1",
    )
    path = tmp_path / "autopilot-1.json"
    path.write_bytes(cfg.to_json())
    assert AutopilotProcessConfig.read(path) == cfg


def test_the_flags_build_the_same_configuration() -> None:
    argv = ["--address", "tcp://127.0.0.1:5000", "--vehicles", "0,1", "--params", '{"1": {"MPC_XY_CRUISE": 3.0}}']
    argv += ["--firmware", "px4,ardupilot", "--gcs-extra-ports", "14552,14553", "--tcp-sim-clients"]
    cfg = _config_from_flags(_parser().parse_args(argv))
    assert cfg == AutopilotProcessConfig(
        address="tcp://127.0.0.1:5000",
        vehicles=(0, 1),
        params={1: {"MPC_XY_CRUISE": 3.0}},
        firmware=(Firmware.PX4, Firmware.ARDUPILOT),
        gcs_extra_ports=(14552, 14553),
        tcp_sim_clients=True,
    )


def test_a_file_that_is_not_a_configuration_is_one_line(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "autopilot.json"
    path.write_text('{"address": "tcp://x:1", "vehicles": "all"}')
    with pytest.raises(ScenarioError, match="not an autopilot process configuration"):
        AutopilotProcessConfig.read(path)
    with caplog.at_level(logging.ERROR):
        assert main(["--config", str(path)]) == 2
    assert "not an autopilot process configuration" in caplog.text
