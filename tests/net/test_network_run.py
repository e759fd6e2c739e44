"""The network through `harness run`: missions talk over the simulated radio (real processes)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from harness.pytest_plugin import RunRecord

pytestmark = pytest.mark.sim
CHATTER = Path(__file__).parent / "scripts" / "chatter.py"
PHASE_S = 0.02


def test_broadcasts_arrive_after_they_were_sent(harness_run: Callable[..., RunRecord]) -> None:
    run = harness_run(mission=CHATTER, vehicles=3, extra=["--network", "builtin"])
    assert run.ok, run.message
    for v in range(3):
        heard = json.loads(run.mission_output(v))
        others = {u for u in range(3) if u != v}
        assert {h["src"] for h in heard} == others
        assert len(heard) == 2 * 10  # 5 m apart: every broadcast of both others arrives
        for h in heard:
            assert h["src"] == h["from"]
            # sent in phase 0 at sent_s, carried in that tick's phase 1, seen at the next phase 0
            assert h["sent_s"] < h["at_s"] < h["sent_s"] + 0.005
            assert h["now_s"] == pytest.approx(h["sent_s"] + PHASE_S, abs=1e-6)
    events = [json.loads(line) for line in (run.out / "network-events.jsonl").read_text().splitlines()]
    assert sum(1 for e in events if e["kind"] == "deliver") == 3 * 2 * 10


def test_out_of_range_nothing_arrives(tmp_path: Path) -> None:
    scenario = tmp_path / "far.toml"
    scenario.write_text(
        f'[vehicles]\ncount = 2\nmission = "{CHATTER}"\nspacing_m = 5.0\n'
        '[network]\nmodel = "builtin"\nparams = { max_range_m = 3.0 }\n'
    )
    out = tmp_path / "run"
    import subprocess
    import sys

    proc = subprocess.run(
        [sys.executable, "-m", "harness.cli", "run", str(scenario), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    run = RunRecord(out, proc.returncode, proc.stdout, proc.stderr)
    assert json.loads(run.mission_output(0)) == [] and json.loads(run.mission_output(1)) == []
    events = [json.loads(line) for line in (out / "network-events.jsonl").read_text().splitlines()]
    assert events and all(e["kind"] == "drop" and e["cause"] == "range" for e in events)


def test_plain_udp_sockets_on_radio_addresses(harness_run: Callable[..., RunRecord]) -> None:
    """Existing swarm code: socket.socket, bind 0.0.0.0:5005 in every vehicle, sendto 10.42.0.255, recvfrom."""
    run = harness_run(
        mission=Path(__file__).parent / "scripts" / "udp_swarm.py", vehicles=3, extra=["--network", "builtin"]
    )
    assert run.ok, run.message
    for v in range(3):
        result = json.loads(run.mission_output(v))
        heard = result["heard"]
        assert len(heard) == 2 * 5
        assert {h["addr"] for h in heard} == {f"10.42.0.{u + 1}" for u in range(3) if u != v}
        assert all(h["addr"] == f"10.42.0.{h['from'] + 1}" for h in heard)
