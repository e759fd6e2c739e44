"""An MCAP file that is valid on disk after every write: a run killed with ``kill -9`` leaves a readable file.

An MCAP file ends with a DataEnd record, the summary section, a Footer and the magic bytes; a file cut
short has no footer and ``mcap.reader.make_reader`` refuses it. :class:`SealedFile` is the stream the mcap
``Writer`` writes into: each of its writes lands, in one ``pwrite``, together with a *seal* — an empty
DataEnd, a Footer saying "no summary" (``summary_start = 0``) and the magic — and the next write overwrites
that seal. So at any instant the file on disk is a complete MCAP file whose messages are read linearly
(``make_reader`` falls back to a streaming read when a file has no summary). The Writer only writes whole
records (a finished chunk, its message indexes), so a message is on disk once its chunk is finalised:
``WorldRecorder.flush`` finalises the chunk in progress, and the run calls it every second of wall time.

At the end, :meth:`SealedFile.unseal` drops the seal and the Writer's ``finish()`` writes the real summary
(with its chunk indexes, for seeking readers) as usual.

The data is in the kernel's page cache as soon as ``pwrite`` returns, so it survives the death of the
process (not a power cut: nothing here calls ``fsync``). The only moment the file is not valid is inside
one ``pwrite`` call (microseconds, once per chunk).
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

from mcap.opcode import Opcode

MCAP_MAGIC = b"\x89MCAP0\r\n"


def _record(opcode: int, body: bytes) -> bytes:
    return struct.pack("<BQ", opcode, len(body)) + body


SEAL = (
    _record(Opcode.DATA_END, struct.pack("<I", 0))  # data section CRC 0: not computed
    + _record(Opcode.FOOTER, struct.pack("<QQI", 0, 0, 0))  # no summary section
    + MCAP_MAGIC
)
"""What follows the data written so far until the Writer finishes the file."""


class SealedFile:
    """A binary stream for ``mcap.writer.Writer`` that keeps the file a valid MCAP file after every write."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self._pos = 0
        self._sealed = True
        self.closed = False

    def _pwrite(self, data: bytes) -> None:
        view = memoryview(data)
        at = self._pos
        while view:
            n = os.pwrite(self._fd, view, at)
            view, at = view[n:], at + n

    def write(self, data: bytes | bytearray | memoryview) -> int:
        chunk = bytes(data)
        self._pwrite(chunk + SEAL if self._sealed else chunk)
        self._pos += len(chunk)
        return len(chunk)

    def tell(self) -> int:
        return self._pos

    def seekable(self) -> bool:
        return False

    def flush(self) -> None:
        """Nothing to do: every write is already in the kernel."""

    def unseal(self) -> None:
        """From now on writes carry no seal (the Writer is about to write the real end of the file)."""
        if self._sealed:
            self._sealed = False
            os.ftruncate(self._fd, self._pos)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            if not self._sealed:
                os.ftruncate(self._fd, self._pos)
            os.close(self._fd)
