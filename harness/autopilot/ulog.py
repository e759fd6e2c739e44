"""A ULog writer: PX4's flight log format (https://docs.px4.io/main/en/dev_log/ulog_file_format.html).

Pure encoding into a growing buffer: the 16-byte header (magic, version 1, start timestamp in µs), the flag
bits message ('B', no flags), then definitions — information ('I'), parameters ('P'), formats ('F') and
subscriptions ('A') — and, in the data section, data ('D') and logged strings ('L'). Every message is
``uint16 size, uint8 type, payload`` in little endian. :meth:`UlogWriter.take` hands over the bytes written
so far; they always end on a message boundary, so every prefix of a log that was flushed is a valid log.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

MAGIC = b"ULog\x01\x12\x35"
VERSION = 1

_TYPES: dict[str, str] = {
    "int8_t": "b",
    "uint8_t": "B",
    "int16_t": "h",
    "uint16_t": "H",
    "int32_t": "i",
    "uint32_t": "I",
    "int64_t": "q",
    "uint64_t": "Q",
    "float": "f",
    "double": "d",
    "bool": "?",
    "char": "c",
}

_MSG = struct.Struct("<HB")
_DATA = ord("D")


@dataclass(frozen=True)
class Topic:
    """A logged message type: its name and fields as ``(type, name)`` with ULog type names (``float[3]`` for an
    array). The first field must be ``uint64_t timestamp`` (µs), as the format requires."""

    name: str
    fields: Sequence[tuple[str, str]]

    def __post_init__(self) -> None:
        if tuple(self.fields[0]) != ("uint64_t", "timestamp"):
            raise ValueError(f"ULog topic {self.name}: the first field must be 'uint64_t timestamp'")

    @property
    def format(self) -> str:
        return f"{self.name}:" + "".join(f"{t} {n};" for t, n in self.fields)

    def packer(self) -> struct.Struct:
        codes = []
        for t, _ in self.fields:
            base, _, count = t.partition("[")
            n = int(count.rstrip("]")) if count else 1
            codes.append(f"{n if n > 1 else ''}{_TYPES[base]}")
        return struct.Struct("<" + "".join(codes))


class UlogWriter:
    """Builds one ULog: definitions first (:meth:`info`, :meth:`param`, then :meth:`add_topics`), then
    :meth:`data` and :meth:`log` in timestamp order."""

    def __init__(self, start_us: int) -> None:
        self._buf = bytearray(MAGIC + bytes([VERSION]) + struct.pack("<Q", start_us))
        self._message(b"B", bytes(16) + bytes(24))  # compat, incompat flags; no appended data
        self._topics: dict[str, tuple[int, struct.Struct]] = {}
        self._data: dict[str, tuple[struct.Struct, int, int]] = {}
        """Per topic: one struct for a whole data message (header, message id, fields), its size field, its id."""

    def _message(self, kind: bytes, payload: bytes) -> None:
        if len(payload) > 0xFFFF:
            raise ValueError(f"ULog message of {len(payload)} bytes is too long")
        self._buf += _MSG.pack(len(payload), kind[0])
        self._buf += payload

    def _key_value(self, kind: bytes, ctype: str, key: str, value: bytes) -> None:
        k = f"{ctype} {key}".encode()
        self._message(kind, bytes([len(k)]) + k + value)

    def info(self, key: str, value: str | int) -> None:
        """An information message ('I'): a string (``char[n]``) or an ``int32_t``."""
        if isinstance(value, str):
            raw = value.encode()
            self._key_value(b"I", f"char[{len(raw)}]", key, raw)
        else:
            self._key_value(b"I", "int32_t", key, struct.pack("<i", value))

    def param(self, name: str, value: float | int) -> None:
        """A parameter ('P'): ``int32_t`` for an int, ``float`` otherwise (before or among the data)."""
        if isinstance(value, int) and not isinstance(value, bool):
            self._key_value(b"P", "int32_t", name, struct.pack("<i", value))
        else:
            self._key_value(b"P", "float", name, struct.pack("<f", float(value)))

    def add_topics(self, topics: Sequence[Topic]) -> None:
        """Define the topics ('F', all of them: the definitions section ends at the first subscription) and
        subscribe to instance 0 of each ('A', message ids in order from 0). Once, after info and parameters."""
        if self._topics:
            raise RuntimeError("ULog: topics are defined once, before any data")
        for topic in topics:
            self._message(b"F", topic.format.encode())
        for msg_id, topic in enumerate(topics):
            self._message(b"A", struct.pack("<BH", 0, msg_id) + topic.name.encode())
            packer = topic.packer()
            self._topics[topic.name] = (msg_id, packer)
            whole = struct.Struct("<HBH" + packer.format[1:])
            self._data[topic.name] = (whole, 2 + packer.size, msg_id)

    def data(self, name: str, values: Sequence[object]) -> None:
        """One sample of topic ``name``: values in field order (arrays flattened), timestamp first."""
        whole, size, msg_id = self._data[name]  # (the bytes of _message(b"D", msg_id + fields), packed at once)
        self._buf += whole.pack(size, _DATA, msg_id, *values)

    def log(self, level: int, timestamp_us: int, text: str) -> None:
        """A logged string ('L'); ``level`` is the syslog level 0 (emergency) … 7 (debug)."""
        self._message(b"L", bytes([ord("0") + min(max(level, 0), 7)]) + struct.pack("<Q", timestamp_us) + text.encode())

    @property
    def pending(self) -> int:
        """Bytes written and not yet taken."""
        return len(self._buf)

    def take(self) -> bytes:
        """The bytes written since the last call (ending on a message boundary)."""
        out = bytes(self._buf)
        self._buf.clear()
        return out
