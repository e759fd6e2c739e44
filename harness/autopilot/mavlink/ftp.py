"""MAVFTP is not offered: every FILE_TRANSFER_PROTOCOL request gets a NAK at once, so a ground station that
tries it first (MAVProxy fetches parameters as ``@PARAM/param.pck`` over MAVFTP) falls back to the
parameter protocol without waiting for its FTP timeout. AUTOPILOT_VERSION does not announce FTP.

MAVFTP payload: seq u16, session u8, opcode u8, size u8, req_opcode u8, burst_complete u8, pad u8,
offset u32, data[239]. A reply carries seq + 1; a NAK (opcode 129) carries the error code in data[0].
"""

from __future__ import annotations

import struct

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.mavlink.messages import MAVLinkMessage, Origin, Out

_HEADER = struct.Struct("<HBBBBBBI")
OP_OPEN_FILE_RO = 4
OP_NAK = 129
ERR_UNKNOWN_COMMAND = 7
ERR_FILE_NOT_FOUND = 10


def nak(mav: mavlink2.MAVLink, m: MAVLinkMessage, origin: Origin) -> list[Out]:
    payload = bytes(m.payload)
    if len(payload) < _HEADER.size:
        return []
    seq, session, opcode, _size, _req, _burst, _pad, _offset = _HEADER.unpack_from(payload)
    if opcode >= 128:  # a reply, not a request
        return []
    error = ERR_FILE_NOT_FOUND if opcode == OP_OPEN_FILE_RO else ERR_UNKNOWN_COMMAND
    reply = _HEADER.pack((seq + 1) & 0xFFFF, session, OP_NAK, 1, opcode, 0, 0, 0) + bytes([error])
    data = list(reply) + [0] * (251 - len(reply))
    return [Out(mav.file_transfer_protocol_encode(0, origin.sysid, origin.compid, data), origin)]
