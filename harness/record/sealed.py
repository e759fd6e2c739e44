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
        self._data_end = 0
        self.closed = False

    def _pwrite(self, data: bytes, at: int) -> None:
        view = memoryview(data)
        while view:
            n = os.pwrite(self._fd, view, at)
            view, at = view[n:], at + n

    def write(self, data: bytes | bytearray | memoryview) -> int:
        chunk = bytes(data)
        try:
            self._pwrite(chunk + SEAL if self._sealed else chunk, self._pos)
        except OSError:
            self._restore()
            raise
        self._pos += len(chunk)
        return len(chunk)

    def _restore(self) -> None:
        """After a write that failed (a full disk: part of it may have landed): the file as it was before, a
        valid MCAP file of everything written so far. Cutting the part off frees the room the seal needs."""
        if self._sealed:
            self._seal_at(self._pos)

    def _seal_at(self, pos: int) -> None:
        try:
            os.ftruncate(self._fd, pos)
            self._pwrite(SEAL, pos)
        except OSError:
            pass  # the file system refuses even that: the file is cut short, readers see the chunks before

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
            self._data_end = self._pos
            os.ftruncate(self._fd, self._pos)

    def abandon(self) -> None:
        """Stop writing after a failed write: the file stays as :meth:`_restore` left it, or, when the end of the
        file was being written, its data and a seal (valid either way)."""
        if not self.closed:
            self.closed = True
            if not self._sealed:  # the end of the file was being written: back to the data and a seal
                self._seal_at(self._data_end)
            os.close(self._fd)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            if not self._sealed:
                os.ftruncate(self._fd, self._pos)
            os.close(self._fd)
