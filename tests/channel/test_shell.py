"""The shell's watchdog reads the clock it is given: a connection that never says HELLO is dropped when the
injected clock passes the handshake limit, not when the wall clock does."""

from __future__ import annotations

from harness.channel import Channel, ChannelConfig, connect_child_socket
from harness.core.clock import NS_PER_S, ManualClock
from harness.wire import protocol as p


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
