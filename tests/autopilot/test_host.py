"""The lockstep host over a real channel: frames in, motors out, several vehicles in one host."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from harness.autopilot.api import FlightMode
from harness.autopilot.host import make_autopilots, run_autopilots
from harness.channel import Channel, ChannelConfig
from harness.core.errors import ScenarioError
from harness.fdm.frame import encode_frame
from harness.wire import protocol as p
from harness.wire.client import ChannelClient
from tests.autopilot.quadsim import QuadSim


def test_host_flies_two_vehicles_through_the_channel() -> None:
    ch = Channel(ChannelConfig(address="tcp://127.0.0.1:0")).start()
    try:
        aps = make_autopilots([0, 1])
        attached: list[int] = []

        class Handle:
            def __init__(self, v: int) -> None:
                self.v = v
                self.closed = False

            def close(self) -> None:
                self.closed = True

        handles: list[Handle] = []

        def attach(ap):  # type: ignore[no-untyped-def]
            attached.append(ap.vehicle)
            handles.append(Handle(ap.vehicle))
            return handles[-1]

        host = threading.Thread(
            target=run_autopilots, args=(ch.address, [0, 1]), kwargs={"autopilots": aps, "attach": attach}
        )
        host.start()
        sims = [QuadSim(np.random.default_rng(v)) for v in (0, 1)]
        phys = ChannelClient.connect(ch.address, p.PeerKind.PHYSICS, "physics", vehicles=(0, 1))
        motors: dict[int, tuple[float, ...]] = {0: (0.0,) * 4, 1: (0.0,) * 4}
        status: dict[int, int] = {}
        try:
            for k in range(250 * 12):
                if k == 500:  # 2 s: both ready; command from outside the lockstep loop, as MAVLink would
                    for v, ap in aps.items():
                        assert ap.action.arm().ok, ap.telemetry.arming_check()
                        assert ap.action.takeoff(3.0 + 2.0 * v).ok
                frames = [sims[v].step(motors[v]) if k else sims[v].frame() for v in (0, 1)]
                phys.send_many(
                    [
                        p.BeginTickAC(f.t_ns, k, v, 2, tuple(sims[v].pos), encode_frame(f))  # type: ignore[arg-type]
                        for v, f in enumerate(frames)
                    ]
                )
                got = 0
                while got < 2:
                    for msg in phys.recv():
                        if isinstance(msg, p.EndTickAC):
                            assert msg.t_ns == frames[msg.vehicle].t_ns
                            motors[msg.vehicle] = msg.motors
                            status[msg.vehicle] = msg.status
                            got += 1
        finally:
            phys.close("done")
        host.join(10.0)
        assert not host.is_alive()
        assert attached == [0, 1] and all(h.closed for h in handles)
        assert abs(sims[0].pos[2] + 3.0) < 0.3 and abs(sims[1].pos[2] + 5.0) < 0.3
        assert aps[0].telemetry.state().mode == FlightMode.HOLD
        armed, landed, main, sub = p.unpack_status(status[1])
        assert armed and landed == 2 and FlightMode.from_px4(main, sub) == FlightMode.HOLD
    finally:
        ch.stop()


def test_host_refuses_bad_vehicle_lists() -> None:
    with pytest.raises(ScenarioError):
        make_autopilots([])
    with pytest.raises(ScenarioError):
        make_autopilots([1, 1])
