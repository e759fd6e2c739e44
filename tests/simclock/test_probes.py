"""Issue 33: waits of every kind a script in the wild uses take their sim time, through ``harness run``.

Each probe (``scripts/probe.py KIND``) waits 2 s one way — a child process, a C-level timed lock wait, a C
extension's sleep or poll, a signal timer, a raw clock read — and prints how much sim time that took. A wait on the
wall clock takes 0.0 s of sim (the sim does not move while the script is busy) or whatever the machine's pace
gives; a wait nobody can end hangs the run. Each must take 2.000 s of sim to one phase and exit 0, at
``--speed max`` and ``--speed 5``, and the two runs must record the same flight."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from harness.pytest_plugin import RunRecord, run_harness
from harness.simclock import shim

pytestmark = pytest.mark.sim

PROBE = Path(__file__).parent / "scripts" / "probe.py"
PHASE_S = 0.02
SECONDS = 2.0

needs_shim = pytest.mark.skipif(shim.compiler() is None, reason="no C compiler: C-level waits stay on the wall clock")


def _probe(tmp_path: Path, kind: str, speed: float | None) -> tuple[RunRecord, dict[str, object]]:
    run = run_harness(tmp_path / f"run-{speed}", PROBE, vehicles=1, duration_s=8, speed=speed, seed=3, args=[kind])
    out = run.mission_output(0)
    lines = [line for line in out.splitlines() if line.startswith("{")]
    assert lines, f"{kind}: the probe printed nothing ({run.message})\n{out[-2000:]}"
    return run, json.loads(lines[-1])


KINDS = [
    "clock_gettime",
    "lock",
    "simple_queue",
    "usleep",
    "zmq_poll",
    "setitimer",
    "subprocess",
    "nested_subprocess",
    "asyncio_subprocess",
    "process_fork",
    "process_forkserver",
    "process_spawn",
]


@needs_shim
@pytest.mark.parametrize("kind", KINDS)
def test_probe_takes_its_sim_time_at_any_speed(tmp_path: Path, kind: str) -> None:
    if kind == "zmq_poll":
        pytest.importorskip("zmq", reason="pyzmq is in the dev extra")
    results = []
    for speed in (None, 5.0):
        run, result = _probe(tmp_path, kind, speed)
        print(
            f"FIGURE probe {kind} speed={speed or 'max'}: {result['dt']} s of sim, exit {run.vehicle(0).mission_exit_code}"
        )
        assert run.vehicle(0).mission_exit_code == 0, run.mission_output(0)[-2000:]
        assert result["ok"] is True, result
        assert result["dt"] == pytest.approx(SECONDS, abs=PHASE_S), result
        # the run ends with the script, in the phase it ended in
        assert run.summary["sim_time_s"] == pytest.approx(SECONDS, abs=2 * PHASE_S + 0.01), run.summary
        results.append((run, result))
    (max_run, max_result), (x5_run, x5_result) = results
    assert max_result == x5_result
    assert max_run.vehicle(0).track == x5_run.vehicle(0).track
