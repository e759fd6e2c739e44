"""The shell's watchdog reads the clock it is given: a connection that never says HELLO is dropped when the
injected clock passes the handshake limit, not when the wall clock does."""

from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path

import pytest

from harness.channel import Channel, ChannelConfig, connect_child_socket
from harness.core.clock import NS_PER_S, ManualClock
from harness.core.errors import SimulationError
from harness.wire import protocol as p
from harness.wire.client import ChannelClient


def test_handshake_deadline_runs_on_the_injected_clock() -> None:
    clock = ManualClock()
    ch = Channel(ChannelConfig(handshake_timeout_s=30.0), clock=clock)
    ch.bind()
    sock = connect_child_socket(ch.address)
    try:
        ch.pump(0.3)  # wall time passes, the injected clock does not
        assert ch.faults == []
        clock.advance_to(31 * NS_PER_S)
        ch.pump(0.1)
        (fault,) = ch.faults
        assert fault.kind == "HANDSHAKE" and "HELLO within 30 s" in fault.reason and not fault.fatal
        sock.settimeout(5)
        frames: list[p.Message] = []
        dec = p.FrameDecoder()
        while data := sock.recv(65536):
            frames += dec.feed(data)
        assert isinstance(frames[0], p.Challenge) and isinstance(frames[-1], p.Error)
        assert frames[-1].code == p.ErrorCode.STALLED
    finally:
        sock.close()
        ch.close()


def test_a_client_waits_for_a_busy_channel_beyond_the_connect_timeout() -> None:
    """A run starting a hundred processes answers their handshakes between starts: a client's connect
    timeout bounds reaching the port, not the channel's answer (``answer_timeout_s``)."""
    ch = Channel(ChannelConfig())
    ch.bind()
    out: dict[str, object] = {}

    def join(answer_timeout_s: float, key: str) -> None:
        try:
            out[key] = ChannelClient.connect(
                ch.address, p.PeerKind.TYPE1, key, timeout_s=0.2, answer_timeout_s=answer_timeout_s
            )
        except SimulationError as exc:
            out[key] = str(exc)

    patient = threading.Thread(target=join, args=(5.0, "patient"))
    hasty = threading.Thread(target=join, args=(0.3, "hasty"))
    try:
        patient.start()
        hasty.start()
        time.sleep(0.8)  # the channel is busy: nobody answers for 0.8 s, four times the connect timeout
        deadline = time.monotonic() + 5.0
        while patient.is_alive() and time.monotonic() < deadline:
            ch.pump(0.05)
        patient.join(1.0)
        hasty.join(1.0)
        assert isinstance(out["patient"], ChannelClient)
        assert isinstance(out["hasty"], str) and "handshake with the channel" in out["hasty"]
        assert "timed out" in out["hasty"]
    finally:
        client = out.get("patient")
        if isinstance(client, ChannelClient):
            client.close()
        ch.close()


@pytest.mark.skipif(sys.platform != "linux", reason="Linux's abstract unix namespace")
def test_an_abstract_unix_address_serves_and_leaves_no_file(tmp_path: Path) -> None:
    name = f"@harness-test-{os.getpid()}"
    ch = Channel(ChannelConfig(address=f"unix://{name}"))
    ch.bind()
    clients: list[ChannelClient] = []
    joiner = threading.Thread(
        target=lambda: clients.append(ChannelClient.connect(ch.address, p.PeerKind.TYPE1, "t1", timeout_s=2.0))
    )
    try:
        joiner.start()
        deadline = time.monotonic() + 5.0
        while not clients and time.monotonic() < deadline:
            ch.pump(0.05)
        joiner.join(1.0)
        assert ch.address == f"unix://{name}" and len(ch.subscribers()) == 1 and clients
        assert name in Path("/proc/net/unix").read_text()
        clients[0].close()
    finally:
        ch.close()
    assert not Path(name).exists() and not any(tmp_path.iterdir())
    assert name not in Path("/proc/net/unix").read_text()
