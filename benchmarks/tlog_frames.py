"""Encoding guard for speed work on the MAVLink codec: is every frame a vehicle sent, as its tlog recorded it,
pymavlink's own encoding of the message it carries?

    .venv/bin/python benchmarks/tlog_frames.py runs/demo/vehicle-0.tlog             # all of a run's vehicles:
    .venv/bin/python benchmarks/tlog_frames.py runs/demo/*.tlog --signing-key-file key.hex

A tlog (``harness/autopilot/sitl.py``) holds every frame a vehicle sent or received, each after its 8-byte
big-endian Unix time in µs. Each frame from the vehicle (system id = the file's vehicle index + 1) is parsed
with pymavlink's ``common`` dialect and packed again with pymavlink's encoder on the frame's own sequence
number (and, for a signed frame, its link id and timestamp, given the key): the bytes must be the recorded
ones. It prints, per file, the frames checked per message type and the mismatches, and exits 0 only when
there are none. Frames of other systems (the ground stations) and of ids outside the dialect are counted,
not checked.
"""

from __future__ import annotations

import argparse
import collections
import re
import sys
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as dialect

_STAMP = 8


def frames_of(path: Path) -> list[bytes]:
    """The frames of a tlog, in order (each after its 8-byte time stamp)."""
    data = path.read_bytes()
    out: list[bytes] = []
    i = 0
    while i + _STAMP + 2 <= len(data):
        start = i + _STAMP
        magic, length = data[start], data[start + 1]
        if magic == 0xFD:
            size = 10 + length + 2 + (13 if data[start + 2] & 0x01 else 0)
        elif magic == 0xFE:
            size = 6 + length + 2
        else:
            raise SystemExit(f"{path}: no MAVLink frame at byte {start} (0x{magic:02x}): not a tlog?")
        out.append(data[start : start + size])
        i = start + size
    return out


def reencoded(msg: Any, frame: bytes, key: bytes | None) -> bytes:
    mav = dialect.MAVLink(None, srcSystem=msg.get_srcSystem(), srcComponent=msg.get_srcComponent())
    mav.seq = msg.get_seq()
    if frame[2] & 0x01:
        if key is None:
            raise SystemExit("signed frames: give --signing-key-file")
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.link_id = frame[-13]
        mav.signing.timestamp = int.from_bytes(frame[-12:-6], "little")
    packed: bytes = msg.pack(mav)
    return packed


def check(path: Path, key: bytes | None) -> tuple[collections.Counter[str], list[str], int]:
    match = re.search(r"vehicle-(\d+)\.tlog$", path.name)
    sysid = int(match.group(1)) + 1 if match else 1
    parser = dialect.MAVLink(None)  # no key: a signature is not checked but rebuilt below, from the key
    parser.robust_parsing = True
    checked: collections.Counter[str] = collections.Counter()
    mismatches: list[str] = []
    others = 0
    for n, frame in enumerate(frames_of(path)):
        if frame[5 if frame[0] == 0xFD else 3] != sysid:
            others += 1
            continue
        msgs = parser.parse_buffer(frame) or []
        if len(msgs) != 1 or isinstance(msgs[0], dialect.MAVLink_bad_data):
            why = msgs[0].reason if msgs else "no message"
            mismatches.append(f"frame {n}: pymavlink does not parse it ({why}): {frame.hex()}")
            continue
        msg = msgs[0]
        if isinstance(msg, dialect.MAVLink_unknown):
            others += 1
            continue
        kind = msg.get_type()
        if reencoded(msg, frame, key) != frame:
            mismatches.append(f"frame {n} {kind} seq {frame[4]}: {frame.hex()}")
        checked[kind] += 1
    return checked, mismatches, others


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("tlogs", nargs="+", type=Path)
    ap.add_argument("--signing-key-file", type=Path, help="the run's key (64 hex characters), for signed frames")
    args = ap.parse_args()
    key = bytes.fromhex(args.signing_key_file.read_text().strip()) if args.signing_key_file else None
    bad = 0
    for path in args.tlogs:
        checked, mismatches, others = check(path, key)
        kinds = ", ".join(f"{k} {n}" for k, n in sorted(checked.items()))
        print(
            f"{path}: {sum(checked.values())} frames of the vehicle checked, {len(mismatches)} differ; {others} others"
        )
        print(f"  {kinds}")
        for m in mismatches[:10]:
            print(f"  {m}")
        bad += len(mismatches)
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
