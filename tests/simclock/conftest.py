"""Fixtures for the lockstep core: real processes over real sockets."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

SCRIPTS = Path(__file__).parent / "scripts"


class Procs:
    """Starts driver and mission processes; kills whatever is left at the end of the test."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.procs: list[subprocess.Popen[str]] = []

    def driver(
        self, role: str, address: str, *args: str, name: str | None = None
    ) -> tuple[subprocess.Popen[str], Path]:
        trace = self.tmp / f"{name or role}-{len(self.procs)}.json"
        cmd = [sys.executable, "-m", "harness.channel.drivers", role, "--address", address, "--trace", str(trace)]
        if name:
            cmd += ["--name", name]
        proc = subprocess.Popen([*cmd, *args], text=True)
        self.procs.append(proc)
        return proc, trace

    def mission(self, address: str, script: str, *args: str, vehicle: int = 0) -> subprocess.Popen[str]:
        cmd = [sys.executable, "-m", "harness.cli", "mission", "--channel", address, "--vehicle", str(vehicle)]
        proc = subprocess.Popen(
            [*cmd, str(SCRIPTS / script), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        self.procs.append(proc)
        return proc

    def channel(self, *args: str) -> tuple[subprocess.Popen[str], str]:
        proc = subprocess.Popen(
            [sys.executable, "-m", "harness.cli", "channel", "--listen", "tcp://127.0.0.1:0", *args],
            stdout=subprocess.PIPE,
            text=True,
        )
        self.procs.append(proc)
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert "listening on" in line, line
        return proc, line.strip().rsplit(" ", 1)[-1]

    def wait_all(self, timeout_s: float = 15.0) -> None:
        """Wait for every process to end (drivers end when physics leaves)."""
        for proc in self.procs:
            proc.wait(timeout_s)

    def close(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGKILL)
            proc.wait(5)


def load(path: Path) -> Any:
    return json.loads(path.read_text())


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Procs]:
    p = Procs(tmp_path)
    try:
        yield p
    finally:
        p.close()
