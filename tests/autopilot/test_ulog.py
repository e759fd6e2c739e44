"""The ULog writer against pyulog (PX4's own parser): definitions, data, logged strings, and that every
flushed prefix of a log being written is a valid log."""

from __future__ import annotations

from pathlib import Path

import pytest

from harness.autopilot.ulog import Topic, UlogWriter

pyulog = pytest.importorskip("pyulog")

POS = Topic("vehicle_local_position", [("uint64_t", "timestamp"), ("float", "x"), ("float[3]", "v"), ("bool", "ok")])
ATT = Topic("vehicle_attitude", [("uint64_t", "timestamp"), ("float[4]", "q")])


def _log(path: Path, data: bytes) -> pyulog.ULog:
    path.write_bytes(data)
    return pyulog.ULog(str(path))


def test_written_log_reads_back_in_pyulog(tmp_path: Path) -> None:
    w = UlogWriter(1_000)
    w.info("sys_name", "PX4")
    w.info("time_ref_utc", 0)
    w.param("MPC_XY_P", 0.95)
    w.param("NAV_DLL_ACT", 2)
    w.add_topics([POS, ATT])
    head = w.take()
    for i in range(50):
        w.data("vehicle_local_position", (i * 20_000, 0.5 * i, 1.0, 2.0, -0.5, i % 2 == 0))
        w.data("vehicle_attitude", (i * 20_000, 1.0, 0.0, 0.0, 0.0))
    w.log(4, 500_000, "Failsafe: no position estimate, LAND")
    u = _log(tmp_path / "a.ulg", head + w.take())
    assert u.start_timestamp == 1_000
    assert u.msg_info_dict["sys_name"] == "PX4" and u.msg_info_dict["time_ref_utc"] == 0
    assert u.initial_parameters["MPC_XY_P"] == pytest.approx(0.95) and u.initial_parameters["NAV_DLL_ACT"] == 2
    pos = u.get_dataset("vehicle_local_position")
    assert list(pos.data["x"][:3]) == [0.0, 0.5, 1.0] and list(pos.data["v[2]"][:2]) == [-0.5, -0.5]
    assert list(pos.data["ok"][:2]) == [1, 0] and len(pos.data["timestamp"]) == 50
    assert len(u.get_dataset("vehicle_attitude").data["q[0]"]) == 50
    (msg,) = u.logged_messages
    assert msg.message == "Failsafe: no position estimate, LAND" and msg.timestamp == 500_000
    # the prefix written so far (what a download during the flight gets) is a log of its own
    part = _log(tmp_path / "b.ulg", head)
    assert {d.name for d in part.data_list} == set() and part.initial_parameters["NAV_DLL_ACT"] == 2


def test_topic_needs_timestamp_first_and_topics_are_defined_once() -> None:
    with pytest.raises(ValueError, match="timestamp"):
        Topic("bad", [("float", "x")])
    w = UlogWriter(0)
    w.add_topics([ATT])
    with pytest.raises(RuntimeError):
        w.add_topics([POS])
