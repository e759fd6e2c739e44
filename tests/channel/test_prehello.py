"""Before its HELLO is accepted a connection may send only a small frame: unauthenticated connections that
announce huge frames are dropped at the length prefix and hold no memory of the channel, while a real peer
(even an autopilot host with a HELLO of 20,000 vehicles) still joins. A real channel process, real sockets."""

from __future__ import annotations

import contextlib
import socket
import struct
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from harness.wire import protocol as p
from harness.wire.client import ChannelClient
from harness.wire.transport import connect, parse_address

HOSTILE = 24
PAYLOAD = 1 << 20  # what each hostile connection streams after its length prefix


def _rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


@pytest.fixture
def channel_process(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[str], str]]:
    cmd = [sys.executable, "-m", "harness.cli", "channel", "--listen", "tcp://127.0.0.1:0", "--name", "guarded"]
    log = tmp_path / "channel.log"  # a file, not a pipe: nobody drains a pipe while the test runs
    with log.open("w") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert "listening on" in line, line + log.read_text()
        yield proc, line.split("listening on ")[1].strip()
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _read_frames(sock: socket.socket) -> list[p.Message]:
    dec = p.FrameDecoder()
    out: list[p.Message] = []
    sock.settimeout(5)
    with contextlib.suppress(OSError):
        while data := sock.recv(65536):
            out += dec.feed(data)
    return out


def test_huge_frames_before_hello_are_refused_and_hold_no_memory(
    channel_process: tuple[subprocess.Popen[str], str],
) -> None:
    proc, address = channel_process
    addr = parse_address(address)
    before = _rss_kib(proc.pid)

    probe = connect(addr)  # one that only announces: it is told why
    probe.sendall(struct.pack(">I", p.MAX_FRAME_BYTES - 1))
    frames = _read_frames(probe)
    probe.close()
    assert isinstance(frames[0], p.Challenge)
    (error,) = frames[1:]
    assert isinstance(error, p.Error) and error.code == p.ErrorCode.MALFORMED
    assert "before its HELLO" in error.message and str(p.MAX_HELLO_BYTES) in error.message

    hostile = [connect(addr) for _ in range(HOSTILE)]
    junk = b"\0" * PAYLOAD
    for sock in hostile:
        sock.settimeout(5)
        with contextlib.suppress(OSError):  # the channel hangs up after the 4-byte prefix
            sock.sendall(struct.pack(">I", p.MAX_FRAME_BYTES - 1) + junk)
    for sock in hostile:
        _read_frames(sock)  # until the channel closed it
        sock.close()
    grown_kib = _rss_kib(proc.pid) - before
    assert grown_kib < 8 * 1024, f"the channel grew by {grown_kib} KiB for {HOSTILE} unauthenticated connections"

    big = ChannelClient.connect(address, p.PeerKind.AUTOPILOT, "host", vehicles=tuple(range(20_000)))
    net = ChannelClient.connect(address, p.PeerKind.TYPE1, "net")
    assert big.welcome.peer_id != net.welcome.peer_id
    big.close()
    net.close()
    assert proc.poll() is None  # still serving
