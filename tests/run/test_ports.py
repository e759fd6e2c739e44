"""Port blocks for a run: the standard ports when free, else a free block the kernel will not hand out."""

from __future__ import annotations

import random
import socket

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
