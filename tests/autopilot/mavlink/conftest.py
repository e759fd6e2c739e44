"""Test rig: a pymavlink ground station on a real UDP socket, and a real Autopilot flown by the small
test quad model (tests/autopilot/quadsim.py) in a thread, with the MAVLink server attached.

The server sends to the GCS socket's port (as it would to 14540 + i); the GCS learns the server's address
from the first datagram and replies there, exactly like MAVSDK listening with ``udpin://``.
"""

from __future__ import annotations

import socket
import threading
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.autopilot.mavlink import MavlinkServer, PortsConfig, SigningConfig
from harness.autopilot.mavlink.codec import signing_timestamp
from harness.core.clock import real_monotonic_ns, real_sleep, real_time_ns
from tests.autopilot.quadsim import QuadSim

Msg = Any


class Gcs:
    """A minimal ground station: one UDP socket, MAVLink 2 (sysid 245 / compid 190 like MAVSDK)."""

    def __init__(self, sysid: int = 245, compid: int = 190, key: bytes | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 21)
        self.sock.bind(("127.0.0.1", 0))
        self.mav = mavlink2.MAVLink(None, sysid, compid)
        if key is not None:
            self.mav.signing.secret_key = key
            self.mav.signing.sign_outgoing = True
            self.mav.signing.link_id = 1
            self.mav.signing.timestamp = signing_timestamp(real_time_ns())
        self.parser = mavlink2.MAVLink(None)
        self.parser.robust_parsing = True
        self.server: tuple[str, int] | None = None
        self.raw: list[bytes] = []
        """Every datagram received (kept only while ``keep_raw``)."""
        self.keep_raw = False

    @property
    def port(self) -> int:
        return int(self.sock.getsockname()[1])

    def close(self) -> None:
        self.sock.close()

    def _read(self, deadline_ns: int) -> list[Msg]:
        left = (deadline_ns - real_monotonic_ns()) / 1e9
        if left <= 0:
            return []
        self.sock.settimeout(left)
        try:
            data, addr = self.sock.recvfrom(65535)
        except (TimeoutError, BlockingIOError):
            return []
        self.server = addr
        if self.keep_raw:
            self.raw.append(data)
        return [m for m in (self.parser.parse_buffer(data) or []) if not isinstance(m, mavlink2.MAVLink_bad_data)]

    def recv(
        self, kind: str | tuple[str, ...], timeout_s: float = 3.0, cond: Callable[[Msg], bool] | None = None
    ) -> Msg:
        """The next message of type ``kind`` (one of them, for a tuple) and ``cond``; earlier others are dropped. A
        HEARTBEAT is the autopilot's (component 1): a PX4 vehicle's camera (component 100) sends its own."""
        kinds = (kind,) if isinstance(kind, str) else kind
        deadline = real_monotonic_ns() + int(timeout_s * 1e9)
        while real_monotonic_ns() < deadline:
            for m in self._read(deadline):
                if m.get_type() in kinds and (cond is None or cond(m)):
                    if m.get_type() == "HEARTBEAT" and m.get_srcComponent() != 1:
                        continue
                    return m
        raise AssertionError(f"no {kind} within {timeout_s} s")

    def collect(self, duration_s: float, kinds: set[str] | None = None) -> list[tuple[int, Msg]]:
        """(wall ns, message) of everything (of ``kinds``) received during ``duration_s``."""
        deadline = real_monotonic_ns() + int(duration_s * 1e9)
        out = []
        while real_monotonic_ns() < deadline:
            for m in self._read(deadline):
                if kinds is None or m.get_type() in kinds:
                    out.append((real_monotonic_ns(), m))
        return out

    def connect(self, timeout_s: float = 3.0) -> Msg:
        """Wait for the vehicle's heartbeat (learns its address) and say hello with ours."""
        hb = self.recv("HEARTBEAT", timeout_s)
        self.send(self.mav.heartbeat_encode(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
        return hb

    def send(self, msg: Msg) -> None:
        assert self.server is not None, "connect() first"
        self.sock.sendto(msg.pack(self.mav), self.server)
        self.mav.seq = (self.mav.seq + 1) % 256

    def send_raw(self, data: bytes) -> None:
        assert self.server is not None
        self.sock.sendto(data, self.server)

    def command(self, command: int, *params: float, target: int = 1, confirmation: int = 0) -> Msg:
        p = [*params, *([0.0] * (7 - len(params)))]
        self.send(self.mav.command_long_encode(target, 1, command, confirmation, *p))
        return self.recv("COMMAND_ACK", 3.0, lambda m: m.command == command)

    def command_int(
        self, command: int, frame: int, p1: float, p2: float, p3: float, p4: float, x: int, y: int, z: float
    ) -> Msg:
        self.send(self.mav.command_int_encode(1, 1, frame, command, 0, 0, p1, p2, p3, p4, x, y, z))
        return self.recv("COMMAND_ACK", 3.0, lambda m: m.command == command)


class Rig:
    """A real Autopilot + the test quad model, stepped in a thread at ``speed`` x real time (None: as fast
    as possible), with a MavlinkServer talking to a ``Gcs``."""

    def __init__(
        self,
        gcs: Gcs,
        seed: int = 7,
        speed: float | None = 1.0,
        signing: SigningConfig | None = None,
        trust_unsigned: Callable[[bool, tuple[str, int]], bool] | None = None,
        **params: float,
    ) -> None:
        self.sim = QuadSim(np.random.default_rng(seed))
        self.ap = Autopilot(AutopilotConfig(params=params))
        self.speed = speed
        self.paused = threading.Event()
        self._stop = threading.Event()
        self._frame = self.sim.frame()
        self.step_s(11.0)  # estimator converged, GPS checks passed for 10 s (EKF2): global position ok, armable
        ports = PortsConfig(api_port_base=gcs.port, gcs_port=0)
        self.server = MavlinkServer(self.ap, 0, ports, signing, trust_unsigned=trust_unsigned)
        self._thread: threading.Thread | None = None

    def step_s(self, seconds: float) -> None:
        for _ in range(round(seconds * 1e9 / self.sim.tick_ns)):
            self._frame = self.sim.step(self.ap.step(self._frame))

    def start(self, stepping: bool = True) -> Rig:
        self.server.start()
        if stepping:
            self._thread = threading.Thread(target=self._loop, daemon=True)
            self._thread.start()
        return self

    def _loop(self) -> None:
        t0_wall = real_monotonic_ns()
        t0_sim = self._frame.t_ns
        while not self._stop.is_set():
            if self.paused.is_set():
                real_sleep(0.01)
                t0_wall, t0_sim = real_monotonic_ns(), self._frame.t_ns
                continue
            self.step_s(0.02)
            if self.speed is not None:
                ahead_ns = (self._frame.t_ns - t0_sim) / self.speed - (real_monotonic_ns() - t0_wall)
                if ahead_ns > 0:
                    real_sleep(ahead_ns / 1e9)
            else:
                real_sleep(0)  # let the server thread run

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        self.server.stop()


@pytest.fixture
def gcs() -> Iterator[Gcs]:
    g = Gcs()
    yield g
    g.close()


@pytest.fixture
def idle_rig(gcs: Gcs) -> Iterator[Rig]:
    """Autopilot that is NOT stepping (a paused simulation): the MAVLink side must still live."""
    rig = Rig(gcs).start(stepping=False)
    gcs.connect()
    yield rig
    rig.stop()


@pytest.fixture
def flying_rig(gcs: Gcs) -> Iterator[Rig]:
    """Autopilot stepped at up to 4x real time."""
    rig = Rig(gcs, speed=4.0).start()
    gcs.connect()
    yield rig
    rig.stop()
