"""Nothing a script does stops the clock for good (issue 22): scripts that never go idle, a client that answers
every answer at once, and a MAVSDK connect that waits for MAVSDK's own time-out all end at the sim time they
would on a real vehicle, through ``harness run``."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from harness.pytest_plugin import run_harness

pytestmark = pytest.mark.sim
SCRIPTS = Path(__file__).resolve().parent / "scripts"


def test_a_script_that_polls_the_clock_without_sleeping_ends_on_time(tmp_path: Path) -> None:
    run = run_harness(tmp_path / "run", SCRIPTS / "poll_clock.py", vehicles=1, duration_s=30)
    assert run.ok, run.message
    out = run.mission_output(0)
    assert "time.time waited until 5.000 s" in out, out
    assert "time.monotonic waited until 7.000 s" in out, out
    assert run.summary["sim_time_s"] < 7.5  # the run ended with the script, not at the duration limit


def test_a_loop_that_never_idles_and_a_thread_that_only_sends_see_time_pass(tmp_path: Path) -> None:
    run = run_harness(tmp_path / "run", SCRIPTS / "never_idle.py", vehicles=1, duration_s=30)
    assert run.ok, run.message
    out = run.mission_output(0)
    assert re.search(r"event loop: 3 s of sim passed after \d+ turns at 3\.0\d\d s", out), out
    assert re.search(r"sender: \d+ datagrams, ended at 5\.0\d\d s", out), out


def test_a_thread_cut_off_by_the_clock_read_limit_finishes_before_a_poller_looks(tmp_path: Path) -> None:
    """A worker whose work reads the clock 2,500 times is stopped by the clock-read limit twice and finishes in the
    phase where the main thread's ``time.sleep`` poll falls due: the main thread sees the result in that phase in
    every round, at any pace (before, both were released by the due round and ran side by side: the main thread saw
    it then or a phase later, 0.040 or 0.060 s, mixed in every run; DroneKit's ``wait_ready`` beside its reader
    taking in a parameter list started a script 0.1 s early in 1 run of 30)."""
    run = run_harness(tmp_path / "run", SCRIPTS / "cut_off.py", vehicles=1, duration_s=30)
    assert run.ok, run.message
    out = run.mission_output(0)
    rounds = re.findall(r"round \d: finished at (\d\.\d+) s, seen at (\d\.\d+) s", out)
    assert len(rounds) == 5, out
    # stopped at the 1,000th and 2,000th read: it finishes two phases (20 ms each) after it began, and is seen there
    assert all(finished == seen == "0.040" for finished, seen in rounds), out


def test_a_command_ack_ping_pong_runs_at_the_loop_rate_in_sim_time(tmp_path: Path) -> None:
    """DroneKit's performance_test.py in our own words: a COMMAND_ACK listener that sends the next command at
    once. It runs its 10 s of sim and exits 0; the vehicle answers at most 8 datagrams per 4 ms loop, so the
    round trips go on at a bounded rate in sim time (before: the run was dropped, "stalled: no END-TICK-0").

    Run twice with one seed, it makes the same round trips at the same sim times. Before, 1 run in 5 made 4,961
    instead of 4,500: DroneKit's reader thread, woken the moment the vehicle answered the main thread's first
    message, took the vehicle's hello heartbeat before or after the main thread had added its capabilities
    listener, and when after, the answer to that request reached the ping-pong's listener too: two commands in
    flight from then on. And a reader polling its socket saw the answer to its last command or not yet, so its
    1 Hz heartbeat took the vehicle's loop budget before or after one more command (4,500 to 4,504). And the main
    thread's ``wait_ready`` poll looked at the parameters while the reader, cut off by the clock-read limit, was
    still taking them in or had finished (4,500 or 4,499: the ping-pong began at 1.20 or 1.10 s)."""
    pytest.importorskip("dronekit", reason="dronekit2 is in the dev extra")
    outs = []
    for k in range(2):
        run = run_harness(
            tmp_path / f"run-{k}",
            SCRIPTS / "ack_pingpong_dronekit.py",
            vehicles=1,
            duration_s=60,
            extra=["--firmware", "ardupilot"],
        )
        assert run.ok, run.message
        outs.append(run.mission_output(0))
    out = outs[0]
    # the same seed flies the same flight: the same ACKs at the same instants of sim time, at any pace
    assert outs[1] == out, f"two runs of one seed differ:\n{out}\n---\n{outs[1]}"
    # one command in flight: every ACK the listener saw answers its own DO_SET_ROI (201), none DroneKit's own
    # capabilities request (520), whose answer would start a second ping-pong beside the first
    assert re.search(r"commands \[\(201, \d+\)\]", out), out
    m = re.search(r"acks (\d+) in (\d+\.\d+) s, gaps (\d+\.\d+) to (\d+\.\d+) s", out)
    assert m, out
    acks, took, longest = int(m.group(1)), float(m.group(2)), float(m.group(4))
    print(f"FIGURE ack ping-pong: {acks} round trips in {took} s of sim, longest gap {longest} s")
    assert 10.0 <= took < 10.1
    assert longest <= 0.02
    per = re.search(r"instants (\d+), at most (\d+) acks at one instant", out)
    assert per, out
    instants, most = int(per.group(1)), int(per.group(2))
    print(f"FIGURE ack ping-pong: {instants} instants of sim time with ACKs, at most {most} at one")
    # the vehicle answers at most 8 datagrams in a loop, and the next step answers the one sent meanwhile: at most 9
    # ACKs in one phase (one instant of sim time); more than one per phase on average, and one at least every phase
    assert most <= 9 and acks > instants and instants >= round(took / 0.02) - 1


def test_a_mavsdk_connect_that_never_succeeds_times_out_on_sim_time(tmp_path: Path) -> None:
    """MAVSDK-Python's show_debug_output.py in our own words: asyncio.wait_for(drone.connect(
    "invalid://bad:connection"), timeout=8) prints "Timed out" after 8 s, as against a real PX4 (before: the
    clock stopped at 0.004 s and the watchdog dropped the script after 30 s)."""
    run = run_harness(tmp_path / "run", SCRIPTS / "connect_timeout.py", vehicles=1, duration_s=30)
    assert run.ok, run.message
    assert "Timed out after 8.000 s" in run.mission_output(0), run.mission_output(0)
