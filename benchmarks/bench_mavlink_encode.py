"""MAVLink encoding cost per message: the vehicle's ``Codec.encode`` against pymavlink's generic ``pack``.

    .venv/bin/python benchmarks/bench_mavlink_encode.py              # unsigned and signed, best of 7
    .venv/bin/python benchmarks/bench_mavlink_encode.py --repeat 15 --number 20000

The messages are what a PX4 vehicle streams (``telemetry.BUILDERS``) plus HEARTBEAT, STATUSTEXT and
COMMAND_ACK, built by the server's own builders from the state of a quad that has taken off and hovers (so
field values, and how much of each payload is trailing zeros, are a flight's). For each message it prints the
µs one frame costs:

- ``codec``: ``Codec.encode`` as the vehicle calls it (next sequence number, signing when on);
- ``pymavlink``: what ``Codec.encode`` did before the precompiled packers — the signing timestamp brought
  up to the wall clock, ``msg.pack`` on pymavlink's ``MAVLink`` object, the sequence number advanced;

then the mean over the messages weighted by the default stream rates (HEARTBEAT 1 Hz, STATUSTEXT and
COMMAND_ACK counted at 0), the speed-up, and ``os.getloadavg()`` — timings are the best of ``--repeat`` runs of
``--number`` frames, which on a shared machine still moves with its load: read them beside it. ``fastcrc``
(pymavlink's optional CRC accelerator) is reported too: without it pymavlink computes the CRC in Python.
"""

from __future__ import annotations

import argparse
import os
import timeit
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import FlightMode, VehicleState
from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.autopilot.mavlink.codec import Codec, MAVLinkMessage, SigningConfig, signing_timestamp
from harness.autopilot.mavlink.heartbeat import heartbeat_message
from harness.autopilot.mavlink.messages import Severity, statustext
from harness.autopilot.mavlink.telemetry import BUILDERS, DEFAULT_INTERVALS_NS
from harness.core.clock import real_time_ns
from harness.fdm.physics import Physics, PhysicsConfig

KEY = bytes(range(32))


def hovering_state() -> VehicleState:
    """A quad 12 s into a flight: armed, taken off to 5 m, holding."""
    phys = Physics(PhysicsConfig(n_vehicles=1, seed=3))
    ap = Autopilot(AutopilotConfig(vehicle=0))
    frames = phys.frames()
    for tick in range(250 * 12):
        frames = phys.step([ap.step(frames[0])])
        if tick % 25 == 0 and not ap.telemetry.state().armed and ap.telemetry.arming_check() == "":
            ap.action.arm()
            ap.action.takeoff(5.0)
    state = ap.telemetry.state()
    assert state.armed and state.mode in (FlightMode.TAKEOFF, FlightMode.HOLD), state.mode
    return state


def messages(mav: mavlink2.MAVLink, state: VehicleState) -> dict[str, tuple[MAVLinkMessage, float]]:
    """(message, rate in Hz) by name."""
    t_ms = state.t_ns // 1_000_000
    out: dict[str, tuple[MAVLinkMessage, float]] = {}
    for msg_id, build in BUILDERS.items():
        msg = build(mav, state, t_ms)
        if msg is not None:
            interval = DEFAULT_INTERVALS_NS.get(msg_id)
            out[msg.get_type()] = (msg, 1e9 / interval if interval else 0.0)
    out["HEARTBEAT"] = (heartbeat_message(mav, state), 1.0)
    out["STATUSTEXT"] = (statustext(mav, Severity.INFO, "Takeoff detected", 1)[0], 0.0)
    out["COMMAND_ACK"] = (mav.command_ack_encode(400, 0, 0, 0, 245, 190), 0.0)
    return out


def pymavlink_encoder(codec: Codec, signing: bool) -> Callable[[MAVLinkMessage], bytes]:
    """``Codec.encode`` as it was: pymavlink's ``pack`` on its ``MAVLink`` object (a separate one)."""
    enc = mavlink2.MAVLink(None, srcSystem=codec.sysid, srcComponent=codec.compid)
    if signing:
        enc.signing.secret_key = KEY
        enc.signing.sign_outgoing = True

    def encode(msg: MAVLinkMessage) -> bytes:
        if enc.signing.sign_outgoing:
            enc.signing.timestamp = max(enc.signing.timestamp, signing_timestamp(real_time_ns()))
        buf: bytes = msg.pack(enc)
        enc.seq = (enc.seq + 1) & 0xFF
        return buf

    return encode


def per_frame_us(encode: Callable[[MAVLinkMessage], bytes], msg: MAVLinkMessage, number: int, repeat: int) -> float:
    return min(timeit.repeat(lambda: encode(msg), number=number, repeat=repeat)) / number * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--number", type=int, default=10_000, help="frames per timing run")
    ap.add_argument("--repeat", type=int, default=7, help="timing runs per figure (the best is kept)")
    args = ap.parse_args()
    state = hovering_state()
    try:
        import fastcrc  # noqa: F401

        crc = "fastcrc installed"
    except ImportError:
        crc = "no fastcrc: pymavlink's CRC in Python"
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; {crc}")
    for signing in (False, True):
        codec = Codec(1, 1, SigningConfig(KEY) if signing else None, real_time_ns)
        reference = pymavlink_encoder(codec, signing)
        msgs = messages(codec.mav, state)
        print(f"\n{'signed' if signing else 'unsigned'} frames, µs per frame (best of {args.repeat} × {args.number})")
        print(f"{'message':<24} {'bytes':>5} {'Hz':>5} {'codec':>7} {'pymavlink':>9} {'speed-up':>8}")
        weighted = [0.0, 0.0, 0.0]  # Hz, codec µs·Hz, pymavlink µs·Hz
        for name, (msg, hz) in sorted(msgs.items()):
            frame = codec.encode(msg)
            ours = per_frame_us(codec.encode, msg, args.number, args.repeat)
            theirs = per_frame_us(reference, msg, args.number, args.repeat)
            print(f"{name:<24} {len(frame):>5} {hz:>5g} {ours:>7.2f} {theirs:>9.2f} {theirs / ours:>7.1f}x")
            weighted[0] += hz
            weighted[1] += ours * hz
            weighted[2] += theirs * hz
        mean_ours, mean_theirs = weighted[1] / weighted[0], weighted[2] / weighted[0]
        print(
            f"{'stream mean':<24} {'':>5} {weighted[0]:>5g} {mean_ours:>7.2f} {mean_theirs:>9.2f} "
            f"{mean_theirs / mean_ours:>7.1f}x"
        )
    print(f"\nload average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
