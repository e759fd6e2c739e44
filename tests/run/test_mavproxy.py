"""MAVProxy (from PyPI) on `harness sitl`'s GCS port, driven non-interactively through its stdin.

It must see the vehicle, download every parameter, and follow the mode changes it commands itself
(arm, takeoff, land) as PX4 reports them in HEARTBEAT.
"""

from __future__ import annotations

import json
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from harness.autopilot.params import PARAM_DEFS

from .flights import start_sitl

pytestmark = pytest.mark.sim


class Console:
    """A line reader over a process's stdout that keeps the whole transcript for the failure message."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        self.proc = proc
        self.lines: queue.Queue[str] = queue.Queue()
        self.transcript: list[str] = []
        threading.Thread(target=self._pump, args=(proc.stdout,), daemon=True).start()

    def _pump(self, stream: object) -> None:
        for line in stream:  # type: ignore[attr-defined]
            self.lines.put(line.rstrip("\n"))

    def expect(self, pattern: str, timeout_s: float) -> re.Match[str]:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            try:
                line = self.lines.get(timeout=0.2)
            except queue.Empty:
                continue
            self.transcript.append(line)
            found = re.search(pattern, line)
            if found:
                return found
        tail = "\n".join(self.transcript[-40:])
        raise AssertionError(f"MAVProxy never printed /{pattern}/ within {timeout_s} s; its last lines:\n{tail}")

    def until(self, command: str, pattern: str, timeout_s: float) -> re.Match[str]:
        """Send ``command`` every second until its output matches (a value that is still on its way)."""
        end = time.monotonic() + timeout_s
        while True:
            self.send(command)
            try:
                return self.expect(pattern, 1.0)
            except AssertionError:
                if time.monotonic() > end:
                    raise

    def send(self, command: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()


def test_mavproxy_sees_the_vehicle_downloads_parameters_and_follows_modes(tmp_path: Path) -> None:
    mavproxy = shutil.which("mavproxy.py", path=str(Path(sys.executable).parent))
    assert mavproxy, "MAVProxy is part of the test setup (dev.py installs it); mavproxy.py not found"
    sitl, port = start_sitl(1, tmp_path / "sitl", stdout=subprocess.DEVNULL)
    proxy: subprocess.Popen[str] | None = None
    try:
        assert sitl.stderr is not None
        threading.Thread(target=sitl.stderr.read, daemon=True).start()  # keep its pipe drained
        proxy = subprocess.Popen(
            [mavproxy, f"--master=udpin:127.0.0.1:{port}", "--source-system=255", "--nowait"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=tmp_path,
        )
        con = Console(proxy)
        con.expect(r"Detected vehicle 1:1", 30)
        got = con.expect(r"Received (\d+) parameters", 60)
        assert int(got.group(1)) == len(PARAM_DEFS)
        where = con.expect(r"Saved \d+ parameters to (\S+)", 10)
        saved = (tmp_path / where.group(1)).read_text().split("\n")
        assert {ln.split()[0] for ln in saved if ln.strip()} == {d.name for d in PARAM_DEFS}

        # MAVProxy's own "takeoff N" is ArduPilot's relative altitude; for PX4 param 7 is AMSL, so a PX4 user
        # sets the takeoff altitude and leaves the position and altitude unset (NaN), as QGroundControl does
        con.send("param set MIS_TAKEOFF_ALT 5")
        con.until("param show MIS_TAKEOFF_ALT", r"MIS_TAKEOFF_ALT\s+5(\.0*)?$", 10)
        con.send("arm throttle")
        con.expect(r"^ARMED", 15)
        con.send("long NAV_TAKEOFF 0 0 0 nan nan nan nan")
        con.expect(r"Mode TAKEOFF", 15)
        con.expect(r"Mode LOITER", 30)  # PX4 holds when the takeoff altitude is reached
        con.send("long NAV_LAND 0 0 0 nan nan nan nan")
        con.expect(r"Mode LAND", 15)
        con.expect(r"^DISARMED", 40)  # touchdown detected, disarmed by the land mode
    finally:
        if proxy is not None and proxy.poll() is None:
            proxy.kill()
            proxy.wait(10)
        sitl.send_signal(signal.SIGINT)
        sitl.wait(20)
    summary = json.loads((tmp_path / "sitl" / "summary.json").read_text())
    assert summary["status"] == "interrupted"
    vehicle = summary["vehicles"][0]
    assert vehicle["crashed"] is False
    assert 4.5 < vehicle["max_altitude_m"] < 6.0  # the takeoff altitude MAVProxy set
