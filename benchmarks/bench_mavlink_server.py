"""The MAVLink servers' CPU per vehicle, robust to a loaded machine: what the autopilot's bell costs (the
server's sim-rate service: telemetry streams built, encoded and sent, heartbeats, the mission and parameter
services' ticks) for N hovering vehicles, each with a listening mission socket and the GCS port, as in a run.

    .venv/bin/python benchmarks/bench_mavlink_server.py [--vehicles 4] [--seconds 20] [--repeat 3]

Physics and autopilots step in this process at 250 Hz; each server is serviced by its autopilot's bell, as
``harness run`` does (no hub thread: nothing else wakes it). Only the bell's calls are timed, in CPU time
(``time.process_time``); the figure is the best of ``--repeat`` runs, in µs per vehicle per second of sim and
per vehicle-tick.
"""

from __future__ import annotations

import argparse
import socket
import time

from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.autopilot.mavlink.server import MavlinkServer
from harness.autopilot.mavlink.transport import LISTEN_HELLO, PortsConfig
from harness.fdm.physics import Physics, PhysicsConfig

TICK_HZ = 250


def measure(n: int, seconds: float) -> tuple[float, int]:
    """CPU µs of the servers' bells per vehicle per sim second, and the number of bells."""
    phys = Physics(PhysicsConfig(n_vehicles=n, seed=1))
    aps = [Autopilot(AutopilotConfig(vehicle=v)) for v in range(n)]
    spent = [0.0]
    calls = [0]
    timing = [False]
    servers: list[MavlinkServer] = []
    missions: list[socket.socket] = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        gcs = probe.getsockname()[1]  # a destination nobody listens on, as a batch run's GCS port
    for v, ap in enumerate(aps):
        server = MavlinkServer(ap, v, PortsConfig(api_port_base=0, gcs_port=gcs))
        mission = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        mission.bind(("127.0.0.1", 0))
        mission.setblocking(False)
        mission.sendto(LISTEN_HELLO, server.local_address("api"))  # a mission's socket on sim time
        servers.append(server)
        missions.append(mission)
    time.sleep(0.05)
    for server, ap in zip(servers, aps, strict=True):
        server.receive(0, 0)
        server.attached(None)  # type: ignore[arg-type]  # the autopilot's bell, without a hub
        bell = server._bell

        def timed(bell=bell) -> None:  # type: ignore[no-untyped-def]
            t0 = time.process_time()
            bell()
            if timing[0]:
                spent[0] += time.process_time() - t0
                calls[0] += 1

        ap.bell.attach(timed)
    frames = phys.frames()
    warm = TICK_HZ * 5
    for tick in range(warm + round(seconds * TICK_HZ)):
        timing[0] = tick >= warm
        motors = [ap.step(f) for ap, f in zip(aps, frames, strict=True)]
        frames = phys.step(motors)
        if tick % 25 == 0 and tick < warm:
            for ap in aps:
                if not ap.telemetry.state().armed and ap.telemetry.arming_check() == "":
                    ap.action.arm()
                    ap.action.takeoff(5.0)
        if tick % TICK_HZ == 0:
            for mission in missions:  # keep the sockets' buffers from filling
                try:
                    while mission.recv(65536):
                        pass
                except BlockingIOError:
                    pass
    for server in servers:
        server.close()
    for mission in missions:
        mission.close()
    return spent[0] / (n * seconds) * 1e6, calls[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vehicles", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=20.0, help="measured sim seconds of hover")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    runs = [measure(a.vehicles, a.seconds) for _ in range(a.repeat)]
    us, calls = min(runs)
    print(
        f"MAVLink servers' bells, {a.vehicles} vehicles, {a.seconds:g} s of sim: {us:.0f} µs CPU per vehicle per sim "
        f"second ({us / TICK_HZ:.2f} per vehicle-tick; {calls / (a.vehicles * a.seconds):.1f} bells a second); best of "
        f"{a.repeat}: {', '.join(f'{r[0]:.0f}' for r in runs)}"
    )


if __name__ == "__main__":
    main()
