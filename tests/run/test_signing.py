"""MAVLink signing on `harness sitl` / `harness run` (issue 17, item 5): a foreign process's unsigned ARM is
ignored on every link it can reach, a signed one arms; the run's own missions fly unsigned; no secret in argv."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from harness.autopilot.mavlink import SigningConfig
from harness.autopilot.mavlink.runlocal import RunLocalPeers, descendants
from harness.record.status import read_summary
from tests.autopilot.mavlink.conftest import Gcs, Rig
from tests.helpers import free_tcp_port

from .flights import start_sitl_ports
from .test_run import ROOT, harness

pytestmark = pytest.mark.sim
PYMAVLINK_TAKEOFF = ROOT / "missions" / "pymavlink_takeoff.py"
HOVER_DRONEKIT = ROOT / "missions" / "hover_dronekit.py"
ARMED = mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED
PREARM_OK = mavutil.mavlink.MAV_SYS_STATUS_PREARM_CHECK


def _key(tmp_path: Path) -> tuple[Path, bytes]:
    key = os.urandom(32)
    path = tmp_path / "signing.key"
    path.write_text(key.hex() + "\n")
    return path, key


def _arm(conn: mavutil.mavfile) -> None:
    conn.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)


class Observer:
    """The ground station's port: heartbeats and SYS_STATUS of vehicle 1 (the vehicle sends there unasked)."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=254)
        self.armed = False

    def pump(self, seconds: float) -> list[bool]:
        """Armed states of every heartbeat within ``seconds``."""
        states = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            m = self.conn.recv_match(type=["HEARTBEAT", "SYS_STATUS"], blocking=True, timeout=0.2)
            if m is not None and m.get_srcSystem() == 1 and m.get_type() == "HEARTBEAT":
                self.armed = bool(m.base_mode & ARMED)
                states.append(self.armed)
        return states

    def wait_armable(self, timeout_s: float) -> None:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            m = self.conn.recv_match(type="SYS_STATUS", blocking=True, timeout=0.5)
            if m is not None and m.get_srcSystem() == 1 and m.onboard_control_sensors_health & PREARM_OK:
                return
        raise AssertionError("the vehicle never became armable")


@pytest.mark.parametrize("firmware", ["px4", "ardupilot"])
def test_unsigned_arm_from_another_process_is_ignored_and_a_signed_one_arms(tmp_path: Path, firmware: str) -> None:
    key_file, key = _key(tmp_path)
    tcp = free_tcp_port()
    extra = ["--signing-key-file", str(key_file), "--firmware", firmware, "--tcp-port-base", str(tcp)]
    proc, gcs_port, api_port = start_sitl_ports(1, tmp_path / "sitl", subprocess.DEVNULL, extra)
    try:
        obs = Observer(gcs_port)
        assert obs.pump(5.0), "no heartbeat on the GCS port"
        if firmware == "px4":
            obs.wait_armable(30.0)
        else:
            obs.pump(5.0)  # ArduCopter: GPS fix and home
        # every link a foreign process reaches: the vehicle's UDP API port, the GCS link (answering the vehicle
        # from the GCS port), and SERIAL0 on TCP for an ArduCopter
        foreign = [mavutil.mavlink_connection(f"udpout:127.0.0.1:{api_port}", source_system=255), obs.conn]
        if firmware == "ardupilot":
            foreign.append(mavutil.mavlink_connection(f"tcp:127.0.0.1:{tcp}", source_system=253))
        states: list[bool] = []
        for _ in range(6):
            for conn in foreign:
                _arm(conn)
            states += obs.pump(0.5)
        states += obs.pump(2.0)
        assert states and not any(states), "an unsigned ARM armed the vehicle"
        tlog = (tmp_path / "sitl" / "vehicle-0.tlog").read_bytes()

        signed = mavutil.mavlink_connection(f"udpout:127.0.0.1:{api_port}", source_system=255)
        signed.setup_signing(key, sign_outgoing=True)
        armed_at = None
        end = time.monotonic() + 15
        while armed_at is None and time.monotonic() < end:
            _arm(signed)
            if any(obs.pump(1.0)):
                armed_at = time.monotonic()
        assert armed_at is not None, "a signed ARM did not arm the vehicle"
        # the recording: no COMMAND_LONG was taken in while only unsigned ones came, the signed one is there
        assert b"\xfd" in tlog and _command_longs(tmp_path / "sitl" / "vehicle-0.tlog", len(tlog)) == (0, 1)
        for conn in foreign:
            conn.close()
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=15)


def _command_longs(tlog: Path, split: int) -> tuple[int, int]:
    """COMMAND_LONG 400 frames recorded before byte ``split`` of the tlog and after it (at least one: 1)."""
    log = mavutil.mavlink_connection(str(tlog))
    before = after = 0
    while (m := log.recv_match(type="COMMAND_LONG")) is not None:
        if m.command != mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            continue
        if log.f.tell() <= split:
            before += 1
        else:
            after = 1
    return before, after


def _argv_of_children(root: int) -> dict[int, bytes]:
    out = {}
    for pid in descendants(root):
        try:
            out[pid] = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            continue
    return out


def _watch_argv(proc: subprocess.Popen[str], seconds: float) -> set[tuple[int, bytes]]:
    """Every (pid, command line) seen under ``proc`` while it runs (a child shows its parent's command line
    between fork and exec, then its own)."""
    seen: set[tuple[int, bytes]] = set()
    end = time.monotonic() + seconds
    while time.monotonic() < end and proc.poll() is None:
        for pid, argv in _argv_of_children(proc.pid).items():
            if argv:  # a process that has exited (a zombie) shows an empty command line
                seen.add((pid, argv))
        time.sleep(0.2)
    return seen


LAUNCH_IN_PROCESS_AUTOPILOT_PROCESS = """
import sys
from pathlib import Path
from harness.run.launcher import Launcher
from harness.scenario.plan import LaunchPlan, MissionPlan
plan = LaunchPlan(vehicles=1, out=Path(sys.argv[1]), missions=(MissionPlan(Path(sys.argv[2])),), duration_s=120,
                  network="builtin", autopilots="process", signing_key_file=Path(sys.argv[3]))
sys.exit(Launcher(plan).run().exit_code)
"""


@pytest.mark.parametrize(
    ("autopilots", "firmware"),
    [("in-process", "px4"), ("process", "px4"), ("in-process", "ardupilot")],
    ids=["in-process", "autopilot-process", "ardupilot-dronekit-tcp"],
)
def test_missions_of_the_run_fly_unsigned_and_no_secret_is_in_any_argv(
    tmp_path: Path, autopilots: str, firmware: str
) -> None:
    key_file, key = _key(tmp_path)
    out = tmp_path / "run"
    common = ["--network", "builtin", "--signing-key-file", str(key_file), "--out", str(out), "--no-progress"]
    if firmware == "ardupilot":  # DroneKit over SERIAL0 (TCP): the run's own TCP client is obeyed unsigned
        proc = harness(
            "run", "--firmware", "ardupilot", "--mission", str(HOVER_DRONEKIT), *common, "--duration", "120", "--", "3"
        )
    elif autopilots == "in-process":
        proc = harness("run", "--mission", str(PYMAVLINK_TAKEOFF), *common, "--duration", "120")
    else:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-c",
                LAUNCH_IN_PROCESS_AUTOPILOT_PROCESS,
                str(out),
                str(PYMAVLINK_TAKEOFF),
                str(key_file),
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
    try:
        seen = _watch_argv(proc, 200)
        _stdout, stderr = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    names = {b" ".join(argv.split(b"\0")[:4]) for _, argv in seen}
    assert any(b"mission" in n for n in names) and any(b"harness.net.subscriber" in n for n in names), names
    if autopilots == "process":
        assert any(b"harness.autopilot.sitl" in n for n in names), names
    for pid, argv in seen:
        assert key.hex().encode() not in argv.lower() and key not in argv, f"process {pid} has the key in argv"
    # the mission (pymavlink or DroneKit, knows no key) armed, took off and landed: the run's processes are obeyed
    summary = read_summary(out)
    mission = (out / "mission-0.stdout").read_text() + (out / "mission-0.stderr").read_text()
    assert proc.returncode == 0 and summary["status"] == "ok", (summary.get("message"), stderr[-1000:], mission[-2000:])
    assert summary["vehicles"][0]["max_altitude_m"] > 2.0 and summary["vehicles"][0]["landed"]


MISSION_SOCKET = """
import socket, sys
from pymavlink.dialects.v20 import common as m
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("127.0.0.1", 0))
print(s.getsockname()[1], flush=True)
mav = m.MAVLink(None, 250, 190)
vehicle = ("127.0.0.1", int(sys.argv[1]))
s.settimeout(3.0)
for line in sys.stdin:  # one unsigned ARM per line; prints the COMMAND_ACK result (or -1)
    s.sendto(mav.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav), vehicle)
    parser, result = m.MAVLink(None), -1
    try:
        while result < 0:
            for msg in parser.parse_buffer(s.recv(65535)) or []:
                if msg.get_type() == "COMMAND_ACK" and msg.command == 400:
                    result = msg.result
    except TimeoutError:
        pass
    print(result, flush=True)
"""


def _soon(condition: Callable[[], bool], timeout_s: float = 2.0) -> bool:
    end = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > end:
            return False
        time.sleep(0.02)
    return True


def test_a_stranger_on_another_address_with_a_missions_port_is_not_the_run(tmp_path: Path) -> None:
    """Issue 36, item 1: a foreign socket bound to 127.0.0.2 on the UDP port of a mission's socket (ports are
    world-readable in /proc/net/udp) sends an unsigned ARM: ignored, before and after the mission itself is
    obeyed unsigned; a signed ground station is obeyed too. Real sockets, a real autopilot and server."""
    key = os.urandom(32)
    gcs = Gcs(key=key)
    rig = Rig(gcs, signing=SigningConfig(key), trust_unsigned=RunLocalPeers(os.getpid())).start()
    vehicle_port = rig.server.local_address("api")[1]
    mission = subprocess.Popen(
        [sys.executable, "-c", MISSION_SOCKET, str(vehicle_port)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        assert mission.stdin is not None and mission.stdout is not None
        port = int(mission.stdout.readline())
        gcs.connect()
        stranger.bind(("127.0.0.2", port))  # the mission's port, another loopback address
        stranger.settimeout(0.2)
        mav = mavlink.MAVLink(None, 250, 190)

        ftp_list = list((bytes(4) + bytes([3, 2]) + bytes(6) + b"/\0").ljust(251, b"\0"))
        asks = [  # every service: a command, MAVFTP, a parameter, the shell, a mission download
            mav.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0),
            mav.file_transfer_protocol_encode(0, 1, 1, ftp_list),
            mav.param_request_read_encode(1, 1, b"MIS_TAKEOFF_ALT", -1),
            mav.serial_control_encode(10, 6, 0, 0, 5, list(b"help\n".ljust(70, b"\0"))),
            mav.mission_request_list_encode(1, 1, 0),
        ]

        def stranger_arms() -> list[object]:
            """Everything the vehicle answers the stranger (nothing: it is no peer, its frames are dropped)."""
            answers = []
            for _ in range(2):
                for msg in asks:
                    stranger.sendto(msg.pack(mav), ("127.0.0.1", vehicle_port))
                try:
                    while True:
                        answers += mavlink.MAVLink(None).parse_buffer(stranger.recv(65535)) or []
                except TimeoutError:
                    pass
            return answers

        assert stranger_arms() == [] and not rig.ap.telemetry.state().armed, "the stranger was obeyed unsigned"
        mission.stdin.write("arm\n")
        mission.stdin.flush()
        assert int(mission.stdout.readline()) == mavlink.MAV_RESULT_ACCEPTED  # the run's own socket: obeyed
        assert _soon(lambda: rig.ap.telemetry.state().armed)
        assert gcs.command(400, 0, 21196).result == mavlink.MAV_RESULT_ACCEPTED  # a signed GCS: obeyed (disarm)
        assert _soon(lambda: not rig.ap.telemetry.state().armed)
        assert stranger_arms() == [] and not rig.ap.telemetry.state().armed, "the stranger was obeyed unsigned"
        assert rig.server.counters().refused_unsigned >= 10
    finally:
        stranger.close()
        mission.kill()
        mission.communicate()
        rig.stop()
        gcs.close()


def test_run_local_peers_trust_only_sockets_of_the_run(tmp_path: Path) -> None:
    """The ownership check itself: a socket of a child is the run's, one of this process or of a stranger is not."""
    mine = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    mine.bind(("127.0.0.1", 0))
    child = subprocess.Popen(
        [sys.executable, "-c", "import socket,sys,time\ns=socket.socket(socket.AF_INET,socket.SOCK_DGRAM)\n"
         "s.bind(('127.0.0.1',0))\nprint(s.getsockname()[1],flush=True)\ntime.sleep(30)"],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert child.stdout is not None
        child_port = int(child.stdout.readline())
        run = RunLocalPeers(os.getpid())  # this test process plays the run: its children are the run's
        assert run.trusted(False, ("127.0.0.1", child_port))
        assert not run.trusted(False, ("127.0.0.1", mine.getsockname()[1]))  # the run's main process: not a child
        assert not RunLocalPeers(child.pid).trusted(False, ("127.0.0.1", child_port))  # a stranger to that run
        assert not run.trusted(True, ("127.0.0.1", child_port))  # a UDP socket is not a TCP peer
        assert not run.trusted(False, ("10.1.2.3", child_port))  # never off loopback
        stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the child's port on another address
        stranger.bind(("127.0.0.2", child_port))
        try:
            assert not run.trusted(False, ("127.0.0.2", child_port))
            assert run.trusted(False, ("127.0.0.1", child_port))
        finally:
            stranger.close()
    finally:
        child.kill()
        child.wait()
        mine.close()
