"""The vehicle link: how physics exchanges one tick with the flight stacks of its vehicles.

``VehicleLink.exchange(t_ns, tick, frames)`` hands every vehicle its sensor frame for the tick and
returns the motor commands each answered with. The first implementation, ``harness.run.link.NativeLink``, is
the paper's BEGIN-TICK-AC / END-TICK-AC through the root channel to our own autopilot.

The same seam fits real flight stacks, which is how real ArduPilot or PX4 binaries could fly in this
physics (not implemented yet; the mapping is fixed here so nothing else has to change):

- **ArduPilot SITL, JSON interface** (``--model JSON``, UDP 9002): SITL sends a binary servo packet
  (magic 18458, frame rate, frame count, 16 PWM values) and blocks until it gets one JSON line back
  (``timestamp`` s, ``imu.gyro`` rad/s and ``imu.accel_body`` m/s² in FRD, ``position`` NED m,
  ``quaternion``, ``velocity`` NED m/s). ``exchange`` would send each frame as that JSON, in lockstep,
  and map PWM 1000–2000 µs to commands 0–1 in ArduCopter's motor order (remapped to PX4 order here).
- **PX4 ``simulator_mavlink``** (TCP 4560, lockstep on ``time_usec``): ``exchange`` would send
  HIL_SENSOR (from ``imu``, ``mag``, ``baro``), HIL_GPS (from ``gps``) and HIL_STATE_QUATERNION
  (``truth``), then wait for HIL_ACTUATOR_CONTROLS with the same ``time_usec`` — PX4's outputs 0–3 are
  already in the quad-X order used here.

Either link replaces only this object; physics, recording and the channel's phases for missions and
network stay as they are.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from harness.fdm.frame import SensorFrame
from harness.wire import protocol as p

Motors = tuple[float, ...]


class VehicleLink(Protocol):
    def exchange(self, t_ns: int, tick: int, frames: Sequence[SensorFrame]) -> list[p.EndTickAC]:
        """Give every vehicle its frame of tick ``tick`` at ``t_ns``; return their END-TICK-AC."""
        ...

    def close(self) -> None: ...
