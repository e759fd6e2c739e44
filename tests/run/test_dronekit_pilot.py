"""DroneKit scripts on the ArduCopter dialect's pilot, attitude, sensor, parameter and reboot services (issue 23),
written here in the style of DroneKit's own examples (channel_overrides.py, set_attitude_target.py,
create_attribute.py, reboot.py, vehicle_state.py; the suite fetches nothing), each on its own vehicle of one
``harness run`` over SITL's SERIAL0 ``tcp:127.0.0.1:5760``. What the vehicles did is read from the recording."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from harness.pytest_plugin import RunRecord

pytestmark = pytest.mark.sim

CHANNELS = """
import time
from dronekit import VehicleMode, connect

vehicle = connect("tcp:127.0.0.1:5760", wait_ready=True)
print("Channel values from RC Tx:", vehicle.channels)
assert all(isinstance(vehicle.channels[str(i)], int) for i in range(1, 9)), vehicle.channels
print("Number of channels: %s" % len(vehicle.channels))
while not vehicle.is_armable:
    time.sleep(1)
vehicle.mode = VehicleMode("ALT_HOLD")
vehicle.channels.overrides = {"3": 1000}  # throttle down to arm, as a pilot would
vehicle.armed = True
while not vehicle.armed:
    time.sleep(0.5)
print("Climbing on throttle 1800")
while vehicle.location.global_relative_frame.alt < 8:
    vehicle.channels.overrides = {"3": 1800}
    time.sleep(0.5)
print("Throttle mid, roll right 1700 for 6 s")
for _ in range(12):
    vehicle.channels.overrides = {"1": 1700, "3": 1500}
    time.sleep(0.5)
print("Ch1 reads %s, Ch3 reads %s" % (vehicle.channels["1"], vehicle.channels["3"]))
vehicle.channels.overrides = {"3": 1500}
time.sleep(2)
vehicle.mode = VehicleMode("LAND")
while vehicle.armed:
    time.sleep(1)
print("Landed")
vehicle.close()
"""

ATTITUDE = """
import math
import time
from dronekit import VehicleMode, connect

vehicle = connect("tcp:127.0.0.1:5760", wait_ready=True)


def to_quaternion(roll=0.0, pitch=0.0, yaw=0.0):
    t0, t1 = math.cos(math.radians(yaw * 0.5)), math.sin(math.radians(yaw * 0.5))
    t2, t3 = math.cos(math.radians(roll * 0.5)), math.sin(math.radians(roll * 0.5))
    t4, t5 = math.cos(math.radians(pitch * 0.5)), math.sin(math.radians(pitch * 0.5))
    return [t0 * t2 * t4 + t1 * t3 * t5, t0 * t3 * t4 - t1 * t2 * t5, t0 * t2 * t5 + t1 * t3 * t4,
            t1 * t2 * t4 - t0 * t3 * t5]


def send_attitude_target(pitch_angle=0.0, thrust=0.5):
    msg = vehicle.message_factory.set_attitude_target_encode(
        0, 1, 1, 0b00000100, to_quaternion(0, pitch_angle, math.degrees(vehicle.attitude.yaw)), 0, 0, 0, thrust)
    vehicle.send_mavlink(msg)


def set_attitude(pitch_angle=0.0, thrust=0.5, duration=0.0):
    send_attitude_target(pitch_angle, thrust)
    start = time.time()
    while time.time() - start < duration:
        send_attitude_target(pitch_angle, thrust)
        time.sleep(0.1)


while not vehicle.is_armable:
    time.sleep(1)
vehicle.mode = VehicleMode("GUIDED_NOGPS")
vehicle.armed = True
while not vehicle.armed:
    time.sleep(1)
thrust = 0.7
while vehicle.location.global_relative_frame.alt < 2.5 * 0.95:
    if vehicle.location.global_relative_frame.alt >= 2.5 * 0.6:
        thrust = 0.6
    set_attitude(thrust=thrust)
    time.sleep(0.2)
print("Reached target altitude %.2f" % vehicle.location.global_relative_frame.alt)
set_attitude(duration=3)
print("Held at %.2f" % vehicle.location.global_relative_frame.alt)
set_attitude(pitch_angle=-5, duration=3)
print("Moved forward")
vehicle.mode = VehicleMode("LAND")
while vehicle.armed:
    time.sleep(1)
vehicle.close()
"""

RAW_IMU = """
import time
from dronekit import connect

vehicle = connect("tcp:127.0.0.1:5760", wait_ready=True)
seen = []


@vehicle.on_message("RAW_IMU")
def listener(self, name, message):
    seen.append(message)


time.sleep(5)
print("RAW_IMU messages in 5 s: %d, zacc %d mG" % (len(seen), seen[-1].zacc))
vehicle.close()
"""

REBOOT_AND_PARAMS = """
import time
from dronekit import connect

vehicle = connect("tcp:127.0.0.1:5760", wait_ready=True)
print("Parameters: %d" % len(vehicle.parameters))
print("RC_OVERRIDE_TIME %s LOIT_SPEED %s" % (vehicle.parameters["RC_OVERRIDE_TIME"], vehicle.parameters["LOIT_SPEED"]))
vehicle.parameters["LOIT_SPEED"] = 900
print("LOIT_SPEED now %s" % vehicle.parameters["LOIT_SPEED"])
vehicle.groundspeed = 15  # DO_CHANGE_SPEED: ArduCopter takes it
texts = []


@vehicle.on_message("STATUSTEXT")
def text(self, name, message):
    texts.append(message.text)


@vehicle.on_message("COMMAND_ACK")
def ack(self, name, message):
    print("ACK of %d: %d" % (message.command, message.result))


vehicle.reboot()
time.sleep(3)
print("After the reboot: %s, mode %s, last heartbeat %.1f s ago" % (texts, vehicle.mode.name, vehicle.last_heartbeat))
vehicle.close()
"""


def test_dronekit_pilot_attitude_sensor_parameter_and_reboot_scripts(tmp_path: Path) -> None:
    # set_attitude_target.py addresses system 1 (SITL's SYSID_THISMAV): its script flies vehicle 0
    scripts = {"attitude": ATTITUDE, "channels": CHANNELS, "raw_imu": RAW_IMU, "reboot": REBOOT_AND_PARAMS}
    entries = []
    for i, (name, text) in enumerate(scripts.items()):
        (tmp_path / f"{name}.py").write_text(text)
        entries.append(
            f'[[vehicles]]\nfirmware = "ardupilot"\nmission = "{tmp_path / name}.py"\nspawn_ned_m = [0.0, {i * 30.0}, 0.0]\n'
        )
    scenario = tmp_path / "pilot.toml"
    scenario.write_text('seed = 3\nspeed = "max"\nduration_s = 200\n' + "".join(entries))
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "harness.cli", "run", str(scenario), "--out", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    run = RunRecord(out, proc.returncode, proc.stdout, proc.stderr)
    assert run.ok, run.message
    outputs = [run.mission_output(i) for i in range(4)]

    # channel_overrides: numeric channels; ALT_HOLD climbed on throttle 1800, held at mid, rolled right (east)
    assert "Channel values from RC Tx" in outputs[1] and "Ch1 reads 1700, Ch3 reads 1500" in outputs[1]
    ch = run.vehicle(1)
    assert ch.max_altitude_m > 7.5 and ch.landed
    climb_end = next(s for s in ch.track if -s["pos_ned_m"][2] > 8.0)
    later = [s for s in ch.track if climb_end["t_s"] + 1.0 <= s["t_s"] <= climb_end["t_s"] + 7.0]
    east = later[-1]["pos_ned_m"][1] - later[0]["pos_ned_m"][1]
    alts = [-s["pos_ned_m"][2] for s in later]
    assert east > 5.0 and max(alts) - min(alts) < 3.0, (east, min(alts), max(alts))

    # set_attitude_target: GUIDED_NOGPS took off on thrust as a climb rate, held, pitched forward, landed
    att = run.vehicle(0)
    assert "Reached target altitude" in outputs[0] and "Moved forward" in outputs[0] and att.landed
    held = float(outputs[0].split("Held at ")[1].split()[0])
    assert 2.0 < held < 3.5 and 2.3 < att.max_altitude_m < 4.0

    # create_attribute: RAW_IMU at DroneKit's 4 Hz, gravity on z
    n, zacc = outputs[2].split("RAW_IMU messages in 5 s: ")[1].split(", zacc ")
    assert 15 <= int(n) <= 25 and -1100 < int(zacc.split()[0]) < -900

    # vehicle_state / reboot: ArduCopter's table, a stored parameter, DO_CHANGE_SPEED 15, a reboot
    count = int(outputs[3].split("Parameters: ")[1].split()[0])
    assert count > 1000 and "RC_OVERRIDE_TIME 3.0 LOIT_SPEED 1250.0" in outputs[3]
    assert "LOIT_SPEED now 900.0" in outputs[3] and "ACK of 246: 0" in outputs[3]
    assert "ArduCopter V4.5.7" in outputs[3] and "mode STABILIZE" in outputs[3]
    assert "ACK of 178" not in outputs[3] or "ACK of 178: 0" in outputs[3]
