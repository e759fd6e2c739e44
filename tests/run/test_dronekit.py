"""DroneKit scripts on ArduCopter vehicles under ``harness run --firmware ardupilot`` (acceptance of issue 12).

The scripts are written here in the style of DroneKit's own examples (simple_goto.py, mission_basic.py,
guided_set_speed_yaw.py: the suite fetches nothing) and connect where those examples and ArduPilot users
connect: SITL's SERIAL0 ``tcp:127.0.0.1:5760`` and the UDP outputs 14550 / 14551. Every vehicle's copy
reaches its own vehicle. Behaviour is checked in the recording: where each vehicle went.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from harness.pytest_plugin import RunRecord, run_harness
from tests.net.flocking import flock_figures, fly_scenario

pytestmark = pytest.mark.sim
MISSIONS = Path(__file__).resolve().parents[2] / "missions"
EARTH_M_PER_DEG = 111_319.5

COMMON = """
import math
import sys
import time

from dronekit import Command, LocationGlobal, LocationGlobalRelative, VehicleMode, connect
from pymavlink import mavutil


def get_location_metres(original, d_north, d_east):
    earth_radius = 6378137.0
    d_lat = d_north / earth_radius
    d_lon = d_east / (earth_radius * math.cos(math.pi * original.lat / 180))
    return LocationGlobal(original.lat + d_lat * 180 / math.pi, original.lon + d_lon * 180 / math.pi, original.alt)


def arm_and_takeoff(vehicle, target_altitude):
    print("Basic pre-arm checks")
    while not vehicle.is_armable:
        print(" Waiting for vehicle to initialise...")
        time.sleep(1)
    print("Arming motors")
    vehicle.mode = VehicleMode("GUIDED")
    vehicle.armed = True
    while not vehicle.armed:
        print(" Waiting for arming...")
        time.sleep(1)
    print("Taking off!")
    vehicle.simple_takeoff(target_altitude)
    while True:
        print(" Altitude: ", vehicle.location.global_relative_frame.alt)
        if vehicle.location.global_relative_frame.alt >= target_altitude * 0.95:
            print("Reached target altitude")
            break
        time.sleep(1)


def rtl_and_wait(vehicle):
    print("Returning to Launch")
    vehicle.mode = VehicleMode("RTL")
    while vehicle.armed:  # ArduCopter disarms by itself once it has landed
        time.sleep(1)
    print("Landed and disarmed")
"""

SIMPLE_GOTO = (
    COMMON
    + """
vehicle = connect("tcp:127.0.0.1:5760", wait_ready=True)
vehicle.wait_ready("autopilot_version")
print("Mode: %s, firmware %s" % (vehicle.mode.name, vehicle.version))
arm_and_takeoff(vehicle, 10)
home = vehicle.location.global_frame
vehicle.airspeed = 3
point1 = get_location_metres(home, 40, 0)
vehicle.simple_goto(LocationGlobalRelative(point1.lat, point1.lon, 20))
time.sleep(30)
point2 = get_location_metres(home, 40, 30)
vehicle.simple_goto(LocationGlobalRelative(point2.lat, point2.lon, 20), groundspeed=8)
time.sleep(20)
rtl_and_wait(vehicle)
vehicle.close()
"""
)

MISSION_BASIC = (
    COMMON
    + """
vehicle = connect("127.0.0.1:14550", wait_ready=True)
cmds = vehicle.commands
cmds.download()
cmds.wait_ready()
home = vehicle.home_location
print("Home: %s" % home)
cmds.clear()
cmds.add(Command(0, 0, 0, mavutil.mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavutil.mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 0, 10))
for d_north, d_east, alt in ((20, -20, 11), (20, 20, 12), (-20, 20, 13), (-20, 20, 13)):
    p = get_location_metres(home, d_north, d_east)
    cmds.add(Command(0, 0, 0, mavutil.mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavutil.mavlink.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, 0, 0, p.lat, p.lon, alt))
cmds.upload()
print("Uploaded %d commands" % cmds.count)
arm_and_takeoff(vehicle, 10)
vehicle.commands.next = 0
vehicle.mode = VehicleMode("AUTO")
seen = []
while True:
    nextwaypoint = vehicle.commands.next
    if not seen or seen[-1] != nextwaypoint:
        seen.append(nextwaypoint)
    if nextwaypoint == 5:  # dummy waypoint: heading to it means waypoint 4 was reached
        print("Exit 'standard' mission when start heading to final waypoint (5)")
        break
    time.sleep(1)
print("next waypoints seen: %s" % seen)
rtl_and_wait(vehicle)
vehicle.close()
"""
)

SPEED_YAW = (
    COMMON
    + """
vehicle = connect("udp:127.0.0.1:14551", wait_ready=True)
arm_and_takeoff(vehicle, 8)


def condition_yaw(heading):
    msg = vehicle.message_factory.command_long_encode(
        0, 0, mavutil.mavlink.MAV_CMD_CONDITION_YAW, 0, heading, 0, 1, 0, 0, 0, 0)
    vehicle.send_mavlink(msg)


def send_ned_velocity(velocity_x, velocity_y, velocity_z, duration):
    msg = vehicle.message_factory.set_position_target_local_ned_encode(
        0, 0, 0, mavutil.mavlink.MAV_FRAME_LOCAL_NED, 0b0000111111000111,
        0, 0, 0, velocity_x, velocity_y, velocity_z, 0, 0, 0, 0, 0)
    for x in range(0, duration):
        vehicle.send_mavlink(msg)
        time.sleep(1)


def goto_position_target_local_ned(north, east, down):
    msg = vehicle.message_factory.set_position_target_local_ned_encode(
        0, 0, 0, mavutil.mavlink.MAV_FRAME_LOCAL_NED, 0b0000111111111000,
        north, east, down, 0, 0, 0, 0, 0, 0, 0, 0)
    vehicle.send_mavlink(msg)


start = vehicle.location.local_frame
print("start NED %s" % start)
condition_yaw(90)
time.sleep(8)
print("heading %s" % vehicle.heading)
send_ned_velocity(2, 0, 0, 6)
send_ned_velocity(0, 2, 0, 6)
send_ned_velocity(0, 0, 0, 3)
print("after velocities NED %s" % vehicle.location.local_frame)
goto_position_target_local_ned(start.north - 10, start.east, -12)
time.sleep(15)
print("after goto NED %s" % vehicle.location.local_frame)
vehicle.mode = VehicleMode("LAND")
while vehicle.armed:
    time.sleep(1)
vehicle.close()
"""
)


def _run(tmp_path: Path, name: str, scenario: str, timeout_s: float = 600) -> RunRecord:
    path = tmp_path / f"{name}.toml"
    path.write_text(scenario)
    out = tmp_path / name
    cmd = [sys.executable, "-m", "harness.cli", "run", str(path), "--out", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    return RunRecord(out, proc.returncode, proc.stdout, proc.stderr)


def closest(track: list[dict[str, object]], n: float, e: float, d: float | None = None) -> float:
    best = math.inf
    for s in track:
        p = s["pos_ned_m"]
        assert isinstance(p, list)
        dist = math.hypot(p[0] - n, p[1] - e) if d is None else math.dist(p, (n, e, d))
        best = min(best, dist)
    return best


def test_dronekit_goto_mission_and_velocity_scripts_fly_ardupilot_vehicles(tmp_path: Path) -> None:
    scripts = {"simple_goto": SIMPLE_GOTO, "mission_basic": MISSION_BASIC, "speed_yaw": SPEED_YAW}
    entries = []
    for i, (name, text) in enumerate(scripts.items()):
        (tmp_path / f"{name}.py").write_text(text)
        entries.append(
            f'[[vehicles]]\nfirmware = "ardupilot"\nmission = "{tmp_path / name}.py"\nspawn_ned_m = [0.0, {i * 60.0}, 0.0]\n'
        )
    run = _run(tmp_path, "dronekit", 'speed = "max"\nduration_s = 400\n' + "".join(entries))
    assert run.ok, run.message + "".join((run.out / f"mission-{i}.stdout").read_text()[-1500:] for i in range(3))

    # simple_goto: 40 m north at 20 m, then 30 m east of that, then home; landed and disarmed by itself
    goto = run.vehicle(0)
    home0 = goto.track[0]["pos_ned_m"]
    assert closest(goto.track, home0[0] + 40, home0[1], home0[2] - 20) < 2.0
    assert closest(goto.track, home0[0] + 40, home0[1] + 30, home0[2] - 20) < 2.0
    assert goto.landed and not goto.summary["armed"] and goto.distance_from_start_m() < 1.5
    assert "Mode: STABILIZE, firmware APM:Copter-4.5.7" in run.mission_output(0)

    # mission_basic: home came from item 0; every waypoint visited in order; back home
    mission = run.vehicle(1)
    home1 = mission.track[0]["pos_ned_m"]
    out = run.mission_output(1)
    assert "Uploaded 5 commands" in out and "next waypoints seen: [1, 2, 3, 4, 5]" in out, out[-800:]
    for dn, de in ((20, -20), (20, 20), (-20, 20)):
        assert closest(mission.track, home1[0] + dn, home1[1] + de) < 2.5, (dn, de)
    assert mission.landed and not mission.summary["armed"] and mission.distance_from_start_m() < 1.5

    # speed/yaw: nose to east, 12 m north then 12 m east by velocity, then a local NED goto 10 m south of start
    vel = run.vehicle(2)
    out = run.mission_output(2)
    heading = float(out.split("heading ")[1].split()[0])
    assert abs(heading - 90) < 5, out
    n0, e0 = vel.track[0]["pos_ned_m"][:2]
    assert closest(vel.track, n0 + 12, e0) < 3.0 and closest(vel.track, n0 + 12, e0 + 12) < 3.0
    assert closest(vel.track, n0 - 10, e0, -12.0) < 1.5
    assert vel.landed and not vel.summary["armed"]


PX4_HOVER = MISSIONS / "hover.py"
ARDU_HOVER = (
    COMMON
    + """
vehicle = connect("tcp:127.0.0.1:5760", wait_ready=True)
arm_and_takeoff(vehicle, float(sys.argv[1]))
time.sleep(10)
vehicle.mode = VehicleMode("LAND")
while vehicle.armed:
    time.sleep(1)
vehicle.close()
"""
)


def test_mixed_swarm_two_px4_two_ardupilot(tmp_path: Path) -> None:
    script = tmp_path / "ardu_hover.py"
    script.write_text(ARDU_HOVER)
    entries = [
        f'[[vehicles]]\nmission = "{PX4_HOVER}"\nargs = ["10"]\n',
        f'[[vehicles]]\nfirmware = "ardupilot"\nmission = "{script}"\nargs = ["6"]\n',
        f'[[vehicles]]\nfirmware = "px4"\nmission = "{PX4_HOVER}"\nargs = ["10"]\n',
        f'[[vehicles]]\nfirmware = "ardupilot"\nmission = "{script}"\nargs = ["8"]\n',
    ]
    run = _run(tmp_path, "mixed", 'speed = "max"\nduration_s = 300\n' + "".join(entries))
    assert run.ok, run.message
    alts = [run.vehicle(i).max_altitude_m for i in range(4)]
    print(f"FIGURE mixed swarm (px4, ardupilot, px4, ardupilot): max altitudes {[round(a, 2) for a in alts]} m")
    px4_alt = run.vehicle(0).max_altitude_m
    assert abs(alts[2] - px4_alt) < 0.5 and 5.5 < alts[1] < 6.6 and 7.5 < alts[3] < 8.6, alts
    assert all(run.vehicle(i).landed for i in range(4))
    assert all(run.vehicle(i).mission_exit_code == 0 for i in range(4))


def test_dronekit_flock_holds_over_the_radio(tmp_path: Path) -> None:
    """The paper's use case with DroneKit: five ArduCopter vehicles flock for 120 s of sim time over the
    built-in radio, more than 3 m apart and together, as the MAVSDK/PX4 flock does (tests/net/test_flock.py)."""
    scenario = (
        f'[vehicles]\ncount = 5\nfirmware = "ardupilot"\nmission = "{MISSIONS / "flock_dronekit.py"}"\nargs = ["120"]\n'
        '[network]\nmodel = "builtin"\nparams = { max_range_m = 2000.0 }\n'
    )
    out = fly_scenario(scenario, tmp_path / "flock")
    f = flock_figures(out, 5)
    flocking_s, min_sep, spread = f.flocking_s, f.min_separation_m, f.max_from_centroid_m
    print(
        f"FIGURE dronekit flock: {flocking_s:.0f} s, min separation {min_sep:.2f} m, max from centroid {spread:.2f} m"
    )
    heard = [json.loads((out / f"mission-{i}.stdout").read_text().strip().splitlines()[-1]) for i in range(5)]
    assert all(len(h["neighbours_heard"]) == 4 for h in heard)
    assert flocking_s >= 120.0 and min_sep > 3.0 and spread < 30.0


def test_same_seed_same_flight_for_dronekit_over_serial0(tmp_path: Path) -> None:
    """DroneKit over TCP (SERIAL0) is as deterministic as over UDP: a settle drains the TCP link first, so
    what the script sent takes effect before the next tick. Twice at max speed: lift-off in the same 20 ms
    sample, the same place at 25 s (to 5 cm). The vehicles are armable once the EKF trusts the GPS (10 s of
    passing checks); the runs end at 30 s of sim time, during the hover."""
    script = tmp_path / "ardu_hover.py"
    script.write_text(ARDU_HOVER)
    runs = [
        run_harness(
            tmp_path / f"run-{k}",
            script,
            vehicles=2,
            seed=5,
            duration_s=30,
            args=["5"],
            extra=["--firmware", "ardupilot"],
        )
        for k in range(2)
    ]
    for run in runs:
        assert run.summary["status"] in ("ok", "failed"), run.message
    for i in range(2):
        lifts = []
        for r in runs:
            track = r.vehicle(i).track
            z0 = track[0]["pos_ned_m"][2]
            lifts.append(next(m["t_s"] for m in track if z0 - m["pos_ned_m"][2] > 0.3))
        assert lifts[0] == lifts[1], f"vehicle {i} lifted off at {lifts}"
        a, b = (r.vehicle(i).position_at(25.0) for r in runs)
        assert -a[2] > 4.5 and math.dist(a, b) < 0.05, (a, b)
