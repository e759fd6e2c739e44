"""Hostile clients over real UDP sockets (issue 36): a PARAM_SET of the wrong type, a parameter file written over
MAVFTP that a reboot must survive, MAVFTP sessions per client, a 1 GiB CRC32 and a shell flood that must not
hold the vehicle's heartbeats, the read-only ULog, ``ver all``, and listeners that announce themselves and go."""

from __future__ import annotations

import json
import platform
import socket
import struct
import threading
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as M

from harness.autopilot.mavlink.ftp import CRC_CHUNK, crc32_px4
from harness.autopilot.mavlink.transport import LISTENERS_MAX, LinkConfig, UdpLink
from harness.core.endpoints import LISTEN_HELLO
from tests.autopilot.mavlink import test_px4_sitl_services as sitl_services
from tests.autopilot.mavlink.conftest import Gcs, Rig
from tests.autopilot.mavlink.test_px4_sitl_services import _FTP, _Ftp, _shell, _Vehicle

vehicle = sitl_services.vehicle
"""The PX4 SITL vehicle fixture, shared with ``test_px4_sitl_services``."""
ACK, NAK = 128, 129
HEARTBEAT_PERIOD_S = 1.0


def _other(gcs: Gcs, sysid: int = 246) -> Gcs:
    """Another ground station on its own socket, talking to the same vehicle."""
    g = Gcs(sysid=sysid)
    g.server = gcs.server
    g.send(g.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
    return g


class HeartbeatWatch:
    """A second client that records when each heartbeat reaches it, on a thread of its own."""

    def __init__(self, gcs: Gcs) -> None:
        self.client = _other(gcs, 247)
        self.times: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        last_hello = 0.0
        while not self._stop.is_set():
            if time.monotonic() - last_hello > 2.0:  # a ground station says hello: it stays a peer
                last_hello = time.monotonic()
                c = self.client
                c.send(c.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
            for _, m in self.client.collect(0.1, {"HEARTBEAT"}):
                if (m.get_srcSystem(), m.get_srcComponent()) == (1, 1):  # the autopilot's, not a camera's
                    self.times.append(time.monotonic())

    def stop(self) -> float:
        """The longest gap between two heartbeats seen (seconds)."""
        self._stop.set()
        self._thread.join(5)
        self.client.close()
        gaps = [b - a for a, b in zip(self.times, self.times[1:], strict=False)]
        assert len(self.times) >= 2, self.times
        return max(gaps)


# ------------------------------------------------------------------ parameters


def test_param_set_of_another_type_is_ignored_as_px4_ignores_it(gcs: Gcs, idle_rig: Rig) -> None:
    """MIS_TAKEOFF_ALT (REAL32) = 3.0 sent as UINT8 was read as the low byte of 3.0f (0) and set: PX4 answers a type
    mismatch with nothing and sets nothing; a STATUSTEXT here says why. The right type still works."""
    before = idle_rig.ap.params["MIS_TAKEOFF_ALT"]
    gcs.send(gcs.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 3.0, M.MAV_PARAM_TYPE_UINT8))
    texts = [m.text for _, m in gcs.collect(0.5, {"STATUSTEXT", "PARAM_VALUE"}) if m.get_type() == "STATUSTEXT"]
    assert "PARAM_SET MIS_TAKEOFF_ALT: UINT8 is not REAL32" in texts, texts
    assert idle_rig.ap.params["MIS_TAKEOFF_ALT"] == before
    gcs.send(gcs.mav.param_set_encode(1, 1, b"SYS_HITL", 1.0, M.MAV_PARAM_TYPE_REAL32))  # an INT32 as a float
    assert not gcs.collect(0.3, {"PARAM_VALUE"})
    gcs.send(gcs.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 3.0, M.MAV_PARAM_TYPE_REAL32))
    assert gcs.recv("PARAM_VALUE", cond=lambda m: m.param_id == "MIS_TAKEOFF_ALT").param_value == 3.0
    assert idle_rig.ap.params["MIS_TAKEOFF_ALT"] == 3.0


def _put(ftp: _Ftp, path: bytes, content: bytes) -> None:
    """Write ``content`` to ``path`` over MAVFTP (create, write 239 bytes at a time, terminate)."""
    h, _ = ftp.one(6, path + b"\0")
    assert h[2] == ACK
    for ofs in range(0, len(content), 239):
        assert ftp.one(7, content[ofs : ofs + 239], session=h[1], offset=ofs)[0][2] == ACK
    ftp.one(1, session=h[1])


@pytest.mark.parametrize(
    "content",
    [
        b'{"MPC_XY_VEL_MAX": 1' + b"0" * 400 + b', "MPC_XY_CRUISE": 7.0}',
        b'{"MPC_XY_VEL_MAX": NaN, "MPC_XY_CRUISE": 7.0}',
        b'{"MPC_XY_VEL_MAX": Infinity, "MPC_XY_CRUISE": 7.0, "' + b"X" * 3000 + b'": 1}',
        b"[" * 5000 + b"]" * 5000,
        b'{"MPC_XY_VEL_MAX": [[[[[[1]]]]]], "MPC_XY_CRUISE": 7.0}',
    ],
    ids=["int-of-401-digits", "nan", "infinity-long-name", "nested-5000", "nested-value"],
)
def test_a_parameter_file_written_over_mavftp_never_stops_a_reboot(
    gcs: Gcs, vehicle: _Vehicle, tmp_path: Path, content: bytes
) -> None:
    """Issue 36, item 4: ``{"MPC_XY_VEL_MAX": 1000…}`` written to /parameters.json, then a reboot: no ACK and an
    OverflowError. Now the reboot is ACCEPTED, what is a finite number is taken, the rest ignored in one line."""
    _put(_Ftp(gcs), b"/parameters.json", content)
    assert (tmp_path / "params" / "vehicle-0.json").read_bytes() == content
    default = vehicle.ap.params.get("MPC_XY_VEL_MAX")
    assert gcs.command(246, 1).result == M.MAV_RESULT_ACCEPTED
    assert vehicle.ap.params.get("MPC_XY_VEL_MAX") == default
    if b"MPC_XY_CRUISE" in content:
        assert vehicle.ap.params.get("MPC_XY_CRUISE") == 7.0
    assert gcs.recv("HEARTBEAT")


# ------------------------------------------------------------------ MAVFTP


def test_mavftp_sessions_belong_to_the_client_that_opened_them(gcs: Gcs, vehicle: _Vehicle) -> None:
    """Issue 36, item 5: of 50 clients that each opened a file, 32 read another client's file (session ids 0-3
    handed out in turn, the oldest taken over). Now each client's sessions are its own, four in all; a fifth
    client is told NoSessionsAvailable (5), and a session id it never opened is InvalidSession (4) for it."""
    clients = [gcs] + [_other(gcs, 200 + i) for i in range(5)]
    ftps = [_Ftp(c) for c in clients]
    try:
        for i, ftp in enumerate(ftps):
            _put(ftp, f"/etc/c{i}.txt".encode(), f"client {i}".encode() * 3)
        opened = [ftp.one(4, f"/etc/c{i}.txt\0".encode()) for i, ftp in enumerate(ftps)]
        assert [h[2] for h, _ in opened] == [ACK] * 4 + [NAK] * 2
        assert [data[0] for _, data in opened[4:]] == [5, 5]  # NoSessionsAvailable
        for i, ((h, _), ftp) in enumerate(zip(opened[:4], ftps, strict=False)):
            assert h[1] == 0  # each client's first session is its session 0
            assert ftp.one(5, session=0, offset=0, size=239)[1] == f"client {i}".encode() * 3
        h, data = ftps[4].one(5, session=0, offset=0, size=239)  # client 0's session id, not client 4's
        assert h[2] == NAK and data[0] == 4
        assert ftps[4].one(1, session=0)[0][2] == NAK  # nor can it close it
        assert ftps[4].one(2)[0][2] == ACK  # a reset closes the sender's own sessions only
        assert ftps[0].one(5, session=0, offset=0, size=239)[1] == b"client 0" * 3
        assert ftps[0].one(1, session=0)[0][2] == ACK  # terminated: a session is free again
        h, _ = ftps[4].one(4, b"/etc/c4.txt\0")
        assert h[2] == ACK and ftps[4].one(5, session=h[1], offset=0, size=239)[1] == b"client 4" * 3
    finally:
        for c in clients[1:]:
            c.close()


def test_the_ulog_cannot_be_renamed_removed_or_replaced(gcs: Gcs, vehicle: _Vehicle, tmp_path: Path) -> None:
    """Issue 36, item 8: the read-only ULog entry could be renamed or removed over MAVFTP."""
    ftp = _Ftp(gcs)
    day = ftp.ls(b"/log")[0][1:].encode()
    name = ftp.ls(b"/log/" + day)[0][1:].split("\t")[0].encode()
    log = b"/log/" + day + b"/" + name
    for op, data in ((13, log + b"\0/etc/stolen.ulg\0"), (8, log + b"\0"), (13, b"/etc/init.d-posix/rcS\0" + log)):
        h, reply = ftp.one(op, data)
        assert h[2] == NAK and reply[0] == 9, (op, reply)  # FileProtected
    assert ftp.ls(b"/log/" + day) and (tmp_path / "vehicle-0.ulg").stat().st_size > 0
    assert not (tmp_path / "fs/vehicle-0/etc/stolen.ulg").exists()
    assert (tmp_path / "fs/vehicle-0/etc/init.d-posix/rcS").exists()


def _crc_of_zeros(size: int) -> int:
    crc, block = 0, bytes(CRC_CHUNK)
    for ofs in range(0, size, CRC_CHUNK):
        crc = crc32_px4(block[: min(CRC_CHUNK, size - ofs)], crc)
    return crc


def test_a_1_gib_crc32_does_not_hold_another_clients_heartbeats(gcs: Gcs, vehicle: _Vehicle, tmp_path: Path) -> None:
    """Issue 36, item 6: CalcFileCRC32 over a 1 GiB sparse file stalled all MAVLink for 2 s per request. Now it is
    worked out a few MiB per tick; the answer is right, and another client's heartbeats keep their period."""
    ftp = _Ftp(gcs)
    size = 1 << 30
    _put(ftp, b"/etc/big.bin", b"")
    assert ftp.one(12, b"/etc/big.bin\0", offset=size)[0][2] == ACK  # truncate up: sparse
    assert (tmp_path / "fs/vehicle-0/etc/big.bin").stat().st_size == size
    expected = _crc_of_zeros(size)
    watch = HeartbeatWatch(gcs)
    time.sleep(2.5)
    start = time.monotonic()
    answer = None
    asked = 0.0
    while answer is None and time.monotonic() - start < 60:
        if time.monotonic() - asked > 5.0:  # a patient client asks again now and then, with a new seq
            asked = time.monotonic()
            ftp.seq += 1
            payload = _FTP.pack(ftp.seq, 0, 14, 14, 0, 0, 0, 0) + b"/etc/big.bin\0\0"
            gcs.send(gcs.mav.file_transfer_protocol_encode(0, 1, 1, list(payload) + [0] * (251 - len(payload))))
        for _, m in gcs.collect(0.2, {"FILE_TRANSFER_PROTOCOL"}):
            raw = bytes(m.payload)
            if raw[3] == ACK and raw[5] == 14:
                answer = struct.unpack("<I", raw[12:16])[0]
    took = time.monotonic() - start
    time.sleep(1.5)
    gap = watch.stop()
    print(f"1 GiB CRC32: {took:.2f} s; longest heartbeat gap seen by another client {gap:.2f} s")
    assert answer == expected
    assert gap < 2 * HEARTBEAT_PERIOD_S, f"a heartbeat was delayed by more than one period: gap {gap:.2f} s"


# ------------------------------------------------------------------ the shell


def test_a_shell_flood_does_not_hold_another_clients_heartbeats(gcs: Gcs, vehicle: _Vehicle) -> None:
    """Issue 36, item 6: a 1.05 MB shell line (15,000 SERIAL_CONTROL chunks) stopped heartbeats for 11.2 s. Now a line
    is at most 256 bytes (the rest dropped: "line too long"), and another client's heartbeats keep their period;
    the console answers the next line as before."""
    watch = HeartbeatWatch(gcs)
    time.sleep(2.5)
    chunk = b"x" * 70
    start = time.monotonic()
    for _ in range(15_000):
        gcs.send(gcs.mav.serial_control_encode(10, 2 | 4, 0, 0, 70, list(chunk)))
    flooding = time.monotonic() - start
    out = _shell(gcs, "\n")
    time.sleep(2.5)
    gap = watch.stop()
    print(
        f"shell flood: 15,000 chunks sent in {flooding:.2f} s; longest heartbeat gap seen by another client {gap:.2f} s"
    )
    assert gap < 2 * HEARTBEAT_PERIOD_S, f"a heartbeat was delayed by more than one period: gap {gap:.2f} s"
    end = time.monotonic() + 15
    while "HW arch" not in out and time.monotonic() < end:  # asked again if lost (a full socket drops datagrams)
        out += _shell(gcs, "ver hw\n")
        out += "".join(bytes(m.data[: m.count]).decode() for _, m in gcs.collect(2.0, {"SERIAL_CONTROL"}))
    assert "nsh: line too long" in out and "HW arch: UAV_HARNESS_SITL" in out, (out, vehicle.attached.server.counters())


def test_a_mavftp_burst_flood_does_not_hold_another_clients_heartbeats(gcs: Gcs, vehicle: _Vehicle) -> None:
    """A client that asks for a burst of the ULog (100 replies each) 3,000 times as fast as it can: another
    client's heartbeats keep their period (the vehicle answers what it can, 20 ms of requests at a time)."""
    ftp = _Ftp(gcs)
    day = ftp.ls(b"/log")[0][1:].encode()
    name = ftp.ls(b"/log/" + day)[0][1:].split("\t")[0].encode()
    h, _ = ftp.one(4, b"/log/" + day + b"/" + name + b"\0")
    assert h[2] == ACK
    watch = HeartbeatWatch(gcs)
    time.sleep(2.5)
    start = time.monotonic()
    for i in range(3_000):
        payload = _FTP.pack(i, h[1], 15, 239, 0, 0, 0, 0)
        gcs.send(gcs.mav.file_transfer_protocol_encode(0, 1, 1, list(payload) + [0] * (251 - len(payload))))
    flooding = time.monotonic() - start
    time.sleep(4.0)
    gap = watch.stop()
    print(f"MAVFTP burst flood: 3,000 requests sent in {flooding:.2f} s; longest heartbeat gap seen by another "
          f"client {gap:.2f} s; {vehicle.attached.server.counters().datagrams_rx} datagrams handled")  # fmt: skip
    assert gap < 2 * HEARTBEAT_PERIOD_S, f"a heartbeat was delayed by more than one period: gap {gap:.2f} s"


def test_shell_lines_are_bounded_per_message_and_consoles_are_per_client(gcs: Gcs, vehicle: _Vehicle) -> None:
    """Ten lines in one message: four run at once, the rest at the next ticks, all answered in order; another
    client's half-typed line does not mix into this one's."""
    other = _other(gcs)
    try:
        part = b"commander st"
        other.send(other.mav.serial_control_encode(10, 2 | 4, 0, 0, len(part), list(part.ljust(70, b"\0"))))
        out = _shell(gcs, "help\n" * 10)
        assert out.count("Builtin Apps:") == 10 and "commander stver" not in out
        assert "armed: False" in _shell(other, "atus\n")  # its own line: "commander status"
    finally:
        other.close()


def test_ver_all_says_what_px4_sitl_says_not_the_hosts_kernel(gcs: Gcs, vehicle: _Vehicle) -> None:
    """Issue 36, item 8: ``ver all`` printed the host's kernel version (``platform.release()``)."""
    out = _shell(gcs, "ver all\n")
    assert "OS: Linux" in out and "FW version: 1.15.0" in out
    assert platform.release() not in out and platform.python_version() not in out


# ------------------------------------------------------------------ listeners


def test_announced_listeners_are_bounded_and_forgotten_once_their_socket_is_closed() -> None:
    """Issue 36, item 6: 1,000 HARNESS-LISTEN peers were kept 25 s after they stopped (every stream sent to each). Now
    a link keeps at most ``LISTENERS_MAX``, and one silent for the peer timeout whose socket is closed is
    forgotten; one still bound stays (a mission that only listens)."""
    link = UdpLink(LinkConfig("api", ("127.0.0.1", 0), None))
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(LISTENERS_MAX + 36)]
    try:
        t0 = time.monotonic_ns()
        link.destinations(t0)
        for s in socks:
            s.bind(("127.0.0.1", 0))
            s.sendto(LISTEN_HELLO, link.local_address)
        time.sleep(0.2)
        assert list(link.receive(512)) == []
        assert len(link.destinations(t0)) == LISTENERS_MAX and link.listeners_refused == 36
        kept = socks[0].getsockname()
        for s in socks[1:]:
            s.close()
        assert len(link.destinations(t0 + 5_000_000_000)) == LISTENERS_MAX  # not yet silent for the timeout
        assert link.destinations(t0 + 11_000_000_000) == [kept]
        assert link.is_sim_peer(kept) and link.has_sim_peers
    finally:
        for s in socks:
            s.close()
        link.close()


def test_a_parameter_file_of_a_megabyte_is_refused_in_one_line(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from harness.autopilot.mavlink.param_store import ParamStore

    path = tmp_path / "p.json"
    path.write_text(json.dumps({f"P{i}": i for i in range(100_000)}))
    assert ParamStore(path).load() == {}
    assert len(caplog.records) == 1 and "larger than" in caplog.records[0].getMessage()
