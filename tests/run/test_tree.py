"""The tree of channels across two hosts from the command line (issue 13): ``harness run --accept`` + ``harness join``.

The two hosts are two network namespaces joined by a veth pair (each with its own loopback, so each host's
MAVLink ports and channel are its own); where namespaces cannot be made (no CAP_NET_ADMIN), two loopback
addresses of this machine.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from harness.record.world import read_topics
from tests.helpers import free_port_on, two_hosts

MISSION = Path(__file__).resolve().parents[2] / "missions" / "takeoff_and_land.py"
pytestmark = pytest.mark.sim


@dataclass(frozen=True)
class Hosts:
    root_ip: str
    root_prefix: tuple[str, ...]
    """Command prefix that runs a process on the root host (``ip netns exec NS``, or nothing)."""
    child_prefix: tuple[str, ...]


@pytest.fixture(scope="module")
def hosts() -> Iterator[Hosts]:
    with two_hosts("10.231.0", ("127.0.0.2", "127.0.0.2")) as h:  # no CAP_NET_ADMIN: two loopback addresses
        yield Hosts(h.a_ip, h.a_prefix, h.b_prefix)


class Root:
    """`harness run` on the root host; its progress lines are collected as they come."""

    def __init__(self, hosts: Hosts, out: Path, secret_file: Path, port: int) -> None:
        self.address = f"tcp://{hosts.root_ip}:{port}"
        self.proc = subprocess.Popen(
            [
                *hosts.root_prefix,
                sys.executable,
                "-m",
                "harness.cli",
                "run",
                "--vehicles",
                "1",
                "--remote-vehicles",
                "2",
                "--mission",
                str(MISSION),
                "--accept",
                self.address,
                "--secret-file",
                str(secret_file),
                "--join-timeout",
                "120",
                "--out",
                str(out),
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.lines: list[str] = []
        self.flying = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line)
            if "in air 3" in line:
                self.flying.set()

    def wait(self, timeout: float) -> tuple[int, str]:
        assert self.proc.stdout is not None
        out = self.proc.stdout.read()
        code = self.proc.wait(timeout)
        self._reader.join(5)
        return code, out + "".join(self.lines)


def _join(hosts: Hosts, address: str, secret_file: Path, out: Path, name: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [
            *hosts.child_prefix,
            sys.executable,
            "-m",
            "harness.cli",
            "join",
            address,
            "--first-vehicle",
            "1",
            "--vehicles",
            "2",
            "--mission",
            str(MISSION),
            "--secret-file",
            str(secret_file),
            "--name",
            name,
            "--out",
            str(out),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )


@pytest.fixture
def secret_file(tmp_path: Path) -> Path:
    path = tmp_path / "secret"
    path.write_text(uuid.uuid4().hex + "\n")
    path.chmod(0o600)
    return path


def test_missions_fly_on_both_hosts(hosts: Hosts, tmp_path: Path, secret_file: Path) -> None:
    port = free_port_on(hosts.root_prefix, hosts.root_ip)
    root = Root(hosts, tmp_path / "root", secret_file, port)
    join = _join(hosts, root.address, secret_file, tmp_path / "child", "host-b")
    try:
        code, text = root.wait(600)
        join_out, _ = join.communicate(timeout=60)
    finally:
        for proc in (root.proc, join):
            with contextlib.suppress(ProcessLookupError):
                proc.kill()
    assert code == 0, text
    assert join.returncode == 0, join_out
    summary = json.loads((tmp_path / "root" / "summary.json").read_text())
    vehicles = summary["vehicles"]
    assert [v["id"] for v in vehicles] == [0, 1, 2]
    assert [v["mission_exit_code"] for v in vehicles] == [0, 0, 0]
    for v in vehicles:  # every vehicle, on either host, took off to 10 m and landed (the root's ground truth)
        assert v["max_altitude_m"] == pytest.approx(10.0, abs=0.6) and v["landed"]
    topics = read_topics(tmp_path / "root" / "world.mcap")
    for i in range(3):
        assert max(-s["pos_ned_m"][2] for s in topics[f"/vehicle/{i}/state"]) > 9.0
    # the child host flew its vehicles: its autopilots wrote their tlogs there, its missions printed there
    assert (tmp_path / "child" / "vehicle-1.tlog").stat().st_size > 10_000
    assert (tmp_path / "child" / "vehicle-2.tlog").stat().st_size > 10_000
    assert "-- Landed" in (tmp_path / "child" / "mission-2.stdout").read_text()
    assert not (tmp_path / "root" / "vehicle-1.tlog").exists()


def test_losing_the_child_ends_the_run_naming_it(hosts: Hosts, tmp_path: Path, secret_file: Path) -> None:
    port = free_port_on(hosts.root_prefix, hosts.root_ip)
    root = Root(hosts, tmp_path / "root", secret_file, port)
    join = _join(hosts, root.address, secret_file, tmp_path / "child", "host-b")
    try:
        assert root.flying.wait(300), "".join(root.lines)
        os.killpg(join.pid, signal.SIGKILL)  # the whole host goes: join and everything it started
        code, text = root.wait(60)
    finally:
        for proc in (root.proc, join):
            with contextlib.suppress(ProcessLookupError):
                proc.kill()
        join.wait(10)
    assert code == 1, text
    summary = json.loads((tmp_path / "root" / "summary.json").read_text())
    assert summary["status"] == "failed"
    assert "host-b" in summary["message"], summary["message"]
    assert "host-b" in text


def test_wrong_secret_is_one_line(tmp_path: Path, secret_file: Path) -> None:
    port = free_port_on((), "127.0.0.1")
    wrong = tmp_path / "wrong"
    wrong.write_text("not-the-secret\n")
    hosts = Hosts("127.0.0.1", (), ())
    root = Root(hosts, tmp_path / "root", secret_file, port)
    try:
        for _ in range(200):  # until the root listens
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=1):
                break
            threading.Event().wait(0.05)
        join = _join(hosts, root.address, wrong, tmp_path / "child", "intruder")
        out, _ = join.communicate(timeout=60)
    finally:
        root.proc.kill()
        root.proc.wait(10)
    assert join.returncode == 2
    lines = [line for line in out.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("harness: harness join: cannot join the run at"), out
