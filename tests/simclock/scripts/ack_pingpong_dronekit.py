"""A DroneKit script that answers every answer at once, in the style of DroneKit's performance_test.py: a
COMMAND_ACK listener sends the next MAV_CMD_DO_SET_ROI the moment an ACK arrives, for 10 s of sim time, and
prints how many round trips it made, the shortest and longest interval between two ACKs, the most ACKs that
arrived at one instant of sim time (within one phase the clock stands still), how many instants had how many ACKs,
which commands the ACKs answered, and a digest of every ACK's sim time (the same seed must give the same)."""

import collections
import hashlib
import itertools
import sys
import time

from dronekit import connect
from pymavlink import mavutil

vehicle = connect(sys.argv[1] if len(sys.argv) > 1 else "tcp:127.0.0.1:5760", wait_ready=True)
stamps: list[float] = []
answered: collections.Counter[int] = collections.Counter()


def send() -> None:
    msg = vehicle.message_factory.command_long_encode(1, 1, mavutil.mavlink.MAV_CMD_DO_SET_ROI, 0, 0, 0, 0, 0, 0, 0, 0)
    vehicle.send_mavlink(msg)


@vehicle.on_message("COMMAND_ACK")
def listener(_vehicle: object, _name: str, message: object) -> None:
    stamps.append(time.monotonic())
    answered[getattr(message, "command", -1)] += 1
    send()


start = time.monotonic()
send()
for _ in range(10):
    time.sleep(1)
vehicle.close()
gaps = [b - a for a, b in itertools.pairwise(stamps)]
instants = [len(list(same)) for _, same in itertools.groupby(stamps)]
print(f"acks {len(stamps)} in {time.monotonic() - start:.3f} s, gaps {min(gaps):.3f} to {max(gaps):.3f} s")
print(f"instants {len(instants)}, at most {max(instants)} acks at one instant")
print(f"acks per instant {sorted(collections.Counter(instants).items())}, commands {sorted(answered.items())}")
print(f"stamps digest {hashlib.sha256(repr(stamps).encode()).hexdigest()[:16]}")
