"""Port blocks for a run: the standard ports when free, else a free block the kernel will not hand out."""

from __future__ import annotations

import random
import socket
import tempfile
from pathlib import Path

import pytest

from harness.run.ports import allocate, ephemeral_range


def test_standard_ports_when_free_else_a_block_below_the_ephemeral_range() -> None:
    first = allocate(5, api_base=24540, gcs=24550)
    try:
        assert (first.api_base, first.gcs) == (24540, 24550)
        # the standard block is held: a second run at the same moment must get another, disjoint one
        second = allocate(5, api_base=24540, gcs=24550, rng=random.Random(1))
        try:
            lo, _ = ephemeral_range()
            ports = set(range(second.api_base, second.api_base + 5)) | {second.gcs}
            assert ports.isdisjoint(set(range(24540, 24545)) | {24550})
            # never inside the range the kernel uses for port-0 binds (autopilot senders, mavsdk_server)
            assert max(ports) < lo
        finally:
            second.release()
    finally:
        first.release()
    # released means bindable again by the run's own processes
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 24550))
    s.close()


def test_gcs_port_a_listener_holds_is_still_the_destination(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A ground station listening on the port does not move the vehicles elsewhere; another run holding it does.
    ``tests/run/test_user_faults.py``: the same with QGroundControl's 14550 and ``harness sitl``."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # this test's locks only
    listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    listener.bind(("127.0.0.1", 0))
    gcs = listener.getsockname()[1]
    try:
        with allocate(2, api_base=24580, gcs=gcs) as first:
            assert first.gcs == gcs  # a ground station listening: that is what it is for
            with allocate(2, api_base=24580, gcs=gcs) as second:  # another run holds it: a port of its own
                assert second.gcs not in (gcs, 0) and second.gcs not in range(second.api_base, second.api_base + 2)
        with allocate(2, api_base=24580) as batch:  # a batch run: a port of its own from the start
            assert batch.gcs not in (gcs, 0, 24580, 24581)
        with allocate(2, api_base=24580, gcs=0) as off:
            assert off.gcs == 0
    finally:
        listener.close()
