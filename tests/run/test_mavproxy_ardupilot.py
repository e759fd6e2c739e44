"""MAVProxy on ``harness sitl --firmware ardupilot --vehicles 2``, with its own ArduPilot commands: it must
see both vehicles as ArduCopter, download their (ArduPilot-named) parameters and fly vehicle 1 with
``mode GUIDED``, ``arm throttle``, ``takeoff 10``, ``wp load`` + ``mode AUTO`` and ``rtl``.

MAVProxy connects to each vehicle's SERIAL0 (TCP 5760 + 10 i, here from a free base), as ``sim_vehicle.py``
starts it: on this shared machine other simulations' vehicles also send to UDP 14550, which would mix
foreign vehicles with the same system ids into a GCS listening there."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from harness.autopilot.mavlink.ardupilot.params import CopterParams
from harness.autopilot.params import Params
from harness.record.world import read_topics
from harness.scenario.sitl_defaults import CMAC
from tests.helpers import free_tcp_port

from .flights import start_sitl
from .test_mavproxy import Console

pytestmark = pytest.mark.sim

ORIGIN = CMAC
"""An ArduCopter vehicle 0's home: ArduPilot SITL's (``sitl_defaults``), where the mission file is."""


def _mission_file(path: Path) -> None:
    """QGC WPL 110, as MAVProxy saves and loads it: line 0 is home, then takeoff and two waypoints."""
    lat, lon, alt = ORIGIN
    d = 25.0 / 111_195  # 25 m north / east (roughly)
    rows = [
        (0, 1, 0, 16, lat, lon, alt),
        (1, 0, 3, 22, 0.0, 0.0, 10.0),
        (2, 0, 3, 16, lat + d, lon, 10.0),
        (3, 0, 3, 16, lat + d, lon + d / 0.676, 10.0),
    ]
    lines = ["QGC WPL 110"]
    for seq, cur, frame, cmd, x, y, z in rows:
        lines.append(f"{seq}\t{cur}\t{frame}\t{cmd}\t0\t0\t0\t0\t{x:.8f}\t{y:.8f}\t{z:.3f}\t1")
    path.write_text("\n".join(lines) + "\n")


def test_mavproxy_flies_an_ardupilot_vehicle_with_its_own_commands(tmp_path: Path) -> None:
    mavproxy = shutil.which("mavproxy.py", path=str(Path(sys.executable).parent))
    assert mavproxy, "MAVProxy is part of the test setup (dev.py installs it); mavproxy.py not found"
    tcp = free_tcp_port()
    extra = ["--firmware", "ardupilot", "--tcp-port-base", str(tcp)]
    sitl, _gcs_port = start_sitl(2, tmp_path / "sitl", stdout=subprocess.DEVNULL, extra=extra)
    proxy: subprocess.Popen[str] | None = None
    _mission_file(tmp_path / "square.txt")
    try:
        assert sitl.stderr is not None
        threading.Thread(target=sitl.stderr.read, daemon=True).start()
        proxy = subprocess.Popen(
            [
                mavproxy,
                f"--master=tcp:127.0.0.1:{tcp}",  # SERIAL0 of each vehicle, as sim_vehicle.py's MAVProxy connects
                f"--master=tcp:127.0.0.1:{tcp + 10}",
                "--source-system=255",
                "--target-system=1",
                "--nowait",
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=tmp_path,
        )
        con = Console(proxy)
        con.expect(r"Detected vehicle [12]:1 on link [01]", 30)
        con.expect(r"Detected vehicle [12]:1 on link [01]", 30)
        got = con.expect(r"Received (\d+) parameters", 60)
        assert int(got.group(1)) == len(CopterParams(Params(), 1))
        con.until("param show RTL_ALT", r"RTL_ALT\s+1500(\.0*)?$", 10)
        # ArduCopter's own table (issue 23): parameters stored without being flown answer too
        con.until("param show LOIT_SPEED", r"LOIT_SPEED\s+1250(\.0*)?$", 10)
        con.until("param show FS_THR_VALUE", r"FS_THR_VALUE\s+975(\.0*)?$", 10)
        con.send("param set RC_OVERRIDE_TIME 5")
        con.until("param show RC_OVERRIDE_TIME", r"RC_OVERRIDE_TIME\s+5(\.0*)?$", 10)

        con.send("mode GUIDED")
        con.expect(r"GUIDED>|Mode GUIDED", 15)
        con.send("arm throttle")
        con.expect(r"^ARMED|ARMED$", 20)
        con.send("takeoff 10")  # ArduCopter: 10 m above home (PX4 would read it as AMSL)
        con.until("status GLOBAL_POSITION_INT", r"relative_alt\W+(9[6-9]\d\d|10[0-4]\d\d)\b", 40)

        con.send("wp load square.txt")
        con.expect(r"Sent all 4 waypoints", 20)
        con.expect(r"MISSION_ACK: TYPE_MISSION: ACCEPTED", 10)
        con.send("mode AUTO")
        con.expect(r"AUTO>|Mode AUTO", 15)
        con.expect(r"Reached command #3", 90)  # the last waypoint (ArduPilot numbering: home is #0)
        con.send("rtl")
        con.expect(r"RTL>|Mode RTL", 15)
        con.expect(r"DISARMED", 120)  # RTL lands at home, then ArduCopter disarms
        # SITL's simulated world, as sim_vehicle.py users change it (issue 34): the wind blows in the physics
        con.send("param set SIM_WIND_DIR 270")
        con.send("param set SIM_WIND_SPD 10")
        con.until("param show SIM_WIND_SPD", r"SIM_WIND_SPD\s+10(\.0*)?$", 10)
    finally:
        if proxy is not None and proxy.poll() is None:
            proxy.kill()
            proxy.wait(10)
        sitl.send_signal(signal.SIGINT)
        sitl.wait(20)
    summary = json.loads((tmp_path / "sitl" / "summary.json").read_text())
    v0, v1 = summary["vehicles"]
    print(
        f"FIGURE mavproxy ardupilot: vehicle 1 max altitude {v0['max_altitude_m']:.2f} m, final NED "
        f"{[round(x, 2) for x in v0['final_position_ned_m']]}, landed {v0['landed']}, armed {v0['armed']}; "
        f"vehicle 2 max altitude {v1['max_altitude_m']:.2f} m"
    )
    assert 14.0 < v0["max_altitude_m"] < 16.5  # the RTL climb to RTL_ALT (15 m), above the 10 m mission
    n, e, _ = v0["final_position_ned_m"]
    assert v0["landed"] and not v0["armed"] and abs(n) < 1.5 and abs(e) < 1.5
    assert v1["max_altitude_m"] < 0.5  # vehicle 2 was not commanded
    winds = [e["detail"] for e in read_topics(tmp_path / "sitl" / "world.mcap")["/sim/events"] if e["kind"] == "sim"]
    assert winds and winds[-1]["vehicle"] == 0 and winds[-1]["wind_ned_m_s"][1] == pytest.approx(10.0), winds
