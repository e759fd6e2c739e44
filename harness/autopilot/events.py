"""What a vehicle's autopilot tells whoever steps its physics and records the run, beside its motors: END-TICK-AC's
``events`` (``harness.wire.protocol``), empty on nearly every tick.

- :class:`~harness.fdm.environment.WorldChange`: its simulated world changed (ArduPilot's ``SIM_*``): applied to the
  physics before the next physics step, recorded;
- :class:`~harness.autopilot.camera.Capture`: its camera took a picture: recorded (``world.mcap``, the 3D view).
"""

from __future__ import annotations

import msgspec

from harness.autopilot.camera import Capture
from harness.fdm.environment import WorldChange

VehicleEvent = WorldChange | Capture

_ENCODER = msgspec.msgpack.Encoder()
_DECODER = msgspec.msgpack.Decoder(list[VehicleEvent])


def encode_events(events: list[VehicleEvent]) -> bytes:
    """``b""`` for none (the usual case: nothing encoded)."""
    return _ENCODER.encode(events) if events else b""


def decode_events(data: bytes) -> list[VehicleEvent]:
    return _DECODER.decode(data) if data else []
