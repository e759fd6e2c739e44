"""MAVFTP (FILE_TRANSFER_PROTOCOL) over a per-vehicle file tree, as PX4 SITL serves its root file system
(PX4 ``mavlink_ftp.cpp``; MAVSDK ``mavlink_ftp_client.cpp`` is the client checked against).

Payload: seq u16, session u8, opcode u8, size u8, req_opcode u8, burst_complete u8, pad u8, offset u32,
data[239]. A reply carries seq + 1, the request's opcode in req_opcode and ACK (128) or NAK (129); a NAK's
data[0] is the error (data[1] the errno for ERR_FAIL_ERRNO).

Opcodes: 0 none, 1 terminate session, 2 reset sessions, 3 list directory (offset = index of the first entry;
entries ``F<name>\\t<size>`` and ``D<name>``, NAK EOF past the last), 4 open read-only (ACK data = u32 size),
5 read, 6 create (truncates), 7 write, 8 remove file, 9 create directory, 10 remove directory (empty), 11 open
write-only, 12 truncate (offset = length), 13 rename (data = ``old\\0new``), 14 CRC32 (PX4's: the CRC-32
table with initial value 0 and no final inversion), 15 burst read (up to ``BURST`` ACKs of 239 bytes from
offset, the last with burst_complete = 1; the client asks for the next burst from where it got to).
16 (list with times) is NAKed UnknownCommand: MAVSDK falls back to 3.

Sessions belong to the peer that opened them (its link and address), as each of PX4's MAVLink instances keeps
its own: a peer numbers its sessions from 0 and can neither read nor close another peer's (InvalidSession).
There are ``MAX_SESSIONS`` in all; when none is free an open is NAKed NoSessionsAvailable, as PX4 answers —
except that a session left idle for ``SESSION_IDLE_NS`` (a client that vanished mid-transfer) is given up for
it. Reset Sessions closes the sender's own. No request holds the vehicle's loop: a read or burst is at most
24 kB, and the CRC32 of a file larger than ``CRC_CHUNK`` is worked out ``CRC_CHUNK`` bytes per server tick,
the answer sent when it is done (a 1 GiB file no longer stalls every link for seconds).

The tree (:func:`vehicle_tree`) is ``<run dir>/fs/vehicle-<i>/``, made the first time a client asks:

    /log/<YYYY-MM-DD>/<HH_MM_SS>.ulg   the vehicle's ULog (a link to <run dir>/vehicle-<i>.ulg, UTC start time)
    /parameters.json                   its saved parameters (a link to <run dir>/params/vehicle-<i>.json)
    /etc/init.d-posix/rcS              what this SITL starts with (our own text)
    /etc/extras/                       empty, as in PX4 SITL

Everything under the tree can be created, written, renamed and removed; the ULog (written by the logger)
is read-only (it cannot be written, truncated, renamed or removed, nor can another file be renamed over it),
and nothing outside the run directory can be reached. Without a run directory (a vehicle
started in-process) every request is NAKed: FileNotFound for opens and lists, UnknownCommand otherwise, so
MAVProxy falls back to the parameter protocol at once.
"""

from __future__ import annotations

import errno
import logging
import os
import posixpath
import struct
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import VehicleState
from harness.autopilot.mavlink.messages import MAVLinkMessage, Origin, Out
from harness.autopilot.mavlink.param_store import ParamStore, store_path
from harness.autopilot.mavlink.service import Service
from harness.autopilot.services import System

log = logging.getLogger(__name__)

_HEADER = struct.Struct("<HBBBBBBI")
DATA_MAX = 239
BURST = 100
"""ACKs per burst (24 kB): a burst at once would overflow a client's socket buffer for a large log."""
MAX_SESSIONS = 4
"""Open files of all peers together (PX4 SITL: one per MAVLink instance, four instances)."""
SESSION_IDLE_NS = 10_000_000_000
"""A session with no request for this long may be given to another open (its client is gone)."""
CRC_CHUNK = 4 << 20
"""Bytes of a file's CRC32 worked out per server tick (a few ms)."""

OP_NONE, OP_TERMINATE, OP_RESET, OP_LIST, OP_OPEN_RO, OP_READ, OP_CREATE, OP_WRITE = range(8)
OP_REMOVE_FILE, OP_MKDIR, OP_RMDIR, OP_OPEN_WO, OP_TRUNCATE, OP_RENAME, OP_CRC32, OP_BURST = range(8, 16)
OP_LIST_WITH_TIME = 16
OP_ACK, OP_NAK = 128, 129
OP_OPEN_FILE_RO = OP_OPEN_RO

ERR_FAIL, ERR_FAIL_ERRNO, ERR_INVALID_DATA_SIZE, ERR_INVALID_SESSION, ERR_NO_SESSIONS = 1, 2, 3, 4, 5
ERR_EOF, ERR_UNKNOWN_COMMAND, ERR_FILE_EXISTS, ERR_FILE_PROTECTED, ERR_FILE_NOT_FOUND = 6, 7, 8, 9, 10

_RCS = """# uav-harness SITL: the flight stack of this vehicle is the harness's own autopilot (PX4 dialect).
# Started by `harness run` / `harness sitl`; parameters in /parameters.json, flight log in /log.
"""


def crc32_px4(data: bytes, crc: int = 0) -> int:
    """PX4's ``crc32part``: the reflected CRC-32 table, initial value 0, no final inversion."""
    return zlib.crc32(data, crc ^ 0xFFFFFFFF) ^ 0xFFFFFFFF


def vehicle_tree(run_dir: Path, vehicle: int, ulog: Path | None, start_unix_s: int) -> Path:
    """Make (once) and return the file tree MAVFTP serves for ``vehicle``."""
    root = run_dir / "fs" / f"vehicle-{vehicle}"
    (root / "etc" / "extras").mkdir(parents=True, exist_ok=True)
    (root / "etc" / "init.d-posix").mkdir(parents=True, exist_ok=True)
    rcs = root / "etc" / "init.d-posix" / "rcS"
    if not rcs.exists():
        rcs.write_text(_RCS)
    if ulog is not None:
        stamp = time.gmtime(start_unix_s)
        day = root / "log" / time.strftime("%Y-%m-%d", stamp)
        day.mkdir(parents=True, exist_ok=True)
        link = day / time.strftime("%H_%M_%S.ulg", stamp)
        for old in (root / "log").glob("*/*.ulg"):  # a run directory used again: the log was started anew
            if old != link and old.is_symlink() and Path(os.path.realpath(old)) == Path(os.path.realpath(ulog)):
                old.unlink()
        if not link.is_symlink() and not link.exists():
            link.symlink_to(os.path.relpath(ulog, day))
    params = root / "parameters.json"
    if not params.is_symlink() and not params.exists():
        params.symlink_to(os.path.relpath(run_dir / "params" / f"vehicle-{vehicle}.json", root))
    return root


def _tree_of(api: System, vehicle: int) -> Path | None:
    """The tree of a vehicle whose run writes a ULog (its directory is the run directory)."""
    logs = api.log_files.files() if api.log_files is not None else []
    if not logs:
        return None
    path, _size, start_unix_s = logs[0]
    store = ParamStore(store_path(path.parent, vehicle))
    if not store.path.exists():
        store.save(api.params)  # the file /parameters.json shows: saved values only (none changed yet)
    return vehicle_tree(path.parent, vehicle, path, start_unix_s)


Peer = tuple[int, tuple[str, int]]
"""(link, address): who opened a session."""


@dataclass(slots=True)
class _Session:
    path: Path
    f: BinaryIO
    size: int
    writable: bool
    used_ns: int = 0


@dataclass(slots=True)
class _CrcJob:
    """A CRC32 worked out over several ticks: the answer goes to ``origin`` with the latest request's seq."""

    origin: Origin
    seq: int
    path: Path
    f: BinaryIO
    crc: int = 0


class FtpError(Exception):
    def __init__(self, code: int, err: int = 0) -> None:
        super().__init__(code, err)
        self.code = code
        self.err = err


def _os_error(e: OSError) -> FtpError:
    if e.errno == errno.ENOENT:
        return FtpError(ERR_FILE_NOT_FOUND)
    if e.errno == errno.EEXIST:
        return FtpError(ERR_FILE_EXISTS)
    return FtpError(ERR_FAIL_ERRNO, e.errno or 0)


class FtpService(Service):
    message_ids = frozenset({mavlink2.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL})

    def __init__(self, api: System, vehicle: int, tree: Callable[[], Path | None] | None = None) -> None:
        super().__init__()
        self.api = api
        self._tree = tree if tree is not None else (lambda: _tree_of(api, vehicle))
        self._root: Path | None = None
        self._sessions: dict[tuple[Peer, int], _Session] = {}
        self._crc_jobs: dict[Peer, _CrcJob] = {}
        self._peer: Peer = (0, ("", 0))
        """The peer of the request being handled."""
        self._now = 0

    @property
    def root(self) -> Path | None:
        if self._root is None:
            try:
                self._root = self._tree()
            except OSError as e:
                log.warning("MAVFTP: cannot make the vehicle's file tree: %s", e)
        return self._root

    def close(self) -> None:
        for s in self._sessions.values():
            s.f.close()
        self._sessions.clear()
        for job in self._crc_jobs.values():
            job.f.close()
        self._crc_jobs.clear()

    @property
    def busy(self) -> bool:
        """A CRC32 is being worked out: the server ticks again soon."""
        return bool(self._crc_jobs)

    def tick(self, state: VehicleState, now: int) -> list[Out]:
        """One ``CRC_CHUNK`` of each CRC32 under way; the answer of those done."""
        outs = []
        for peer, job in list(self._crc_jobs.items()):
            try:
                block = job.f.read(CRC_CHUNK)
            except OSError as e:
                del self._crc_jobs[peer]
                job.f.close()
                err = _os_error(e)
                body = bytes([err.code, err.err]) if err.code == ERR_FAIL_ERRNO else bytes([err.code])
                outs.append(self._out(self._pack(job.seq + 1, 0, OP_NAK, OP_CRC32, 0, 0, body), job.origin))
                continue
            if block:
                job.crc = crc32_px4(block, job.crc)
                continue
            del self._crc_jobs[peer]
            job.f.close()
            reply = self._pack(job.seq + 1, 0, OP_ACK, OP_CRC32, 0, 0, struct.pack("<I", job.crc))
            outs.append(self._out(reply, job.origin))
        return outs

    # ------------------------------------------------------------------ protocol
    def handle(self, m: MAVLinkMessage, origin: Origin, now: int) -> list[Out]:
        payload = bytes(m.payload)
        if len(payload) < _HEADER.size:
            return []
        seq, session, opcode, size, _req, _burst, _pad, offset = _HEADER.unpack_from(payload)
        if opcode >= OP_ACK:  # a reply, not a request
            return []
        data = payload[_HEADER.size : _HEADER.size + min(size, DATA_MAX)]
        root = self.root
        self._peer, self._now = (origin.link, origin.addr), now
        try:
            if root is None:
                raise FtpError(ERR_FILE_NOT_FOUND if opcode in (OP_OPEN_RO, OP_LIST) else ERR_UNKNOWN_COMMAND)
            if opcode == OP_BURST:
                return [self._out(p, origin) for p in self._burst(seq, session, offset)]
            if opcode == OP_CRC32:
                return self._crc_request(root, seq, data, origin)
            reply_session, reply_offset, body = self._execute(root, opcode, session, offset, size, data)
        except FtpError as e:
            body = bytes([e.code, e.err]) if e.code == ERR_FAIL_ERRNO else bytes([e.code])
            return [self._out(self._pack(seq + 1, session, OP_NAK, opcode, 0, offset, body), origin)]
        return [self._out(self._pack(seq + 1, reply_session, OP_ACK, opcode, 0, reply_offset, body), origin)]

    def _out(self, payload: bytes, origin: Origin) -> Out:
        assert self.mav is not None
        data = list(payload) + [0] * (251 - len(payload))
        return Out(self.mav.file_transfer_protocol_encode(0, origin.sysid, origin.compid, data), origin)

    @staticmethod
    def _pack(seq: int, session: int, opcode: int, req: int, burst_complete: int, offset: int, body: bytes) -> bytes:
        return _HEADER.pack(seq & 0xFFFF, session, opcode, len(body), req, burst_complete, 0, offset) + body

    def _execute(
        self, root: Path, op: int, session: int, offset: int, size: int, data: bytes
    ) -> tuple[int, int, bytes]:
        """(session, offset, data) of the ACK; raises FtpError for a NAK."""
        if op == OP_NONE:
            return session, 0, b""
        if op == OP_TERMINATE:
            s = self._sessions.pop((self._peer, session), None)
            if s is None:
                raise FtpError(ERR_INVALID_SESSION)
            s.f.close()
            return session, 0, b""
        if op == OP_RESET:  # the sender's own sessions (another client's transfer goes on)
            for key in [k for k in self._sessions if k[0] == self._peer]:
                self._sessions.pop(key).f.close()
            return session, 0, b""
        if op == OP_LIST:
            return session, offset, self._list(root, data, offset)
        if op in (OP_OPEN_RO, OP_CREATE, OP_OPEN_WO):
            sid, size = self._open(root, op, data)
            return sid, 0, struct.pack("<I", size) if op == OP_OPEN_RO else b""
        if op == OP_READ:
            return session, offset, self._read(session, offset, min(size, DATA_MAX) or DATA_MAX)
        if op == OP_WRITE:
            s = self._session(session)
            if not s.writable:
                raise FtpError(ERR_FILE_PROTECTED)
            try:
                s.f.seek(offset)
                s.f.write(data)
                s.f.flush()
            except OSError as e:
                raise _os_error(e) from None
            return session, offset, b""
        path = self._path(root, data.split(b"\0", 1)[0])
        try:
            if op == OP_REMOVE_FILE:
                if path.is_dir() and not path.is_symlink():
                    raise FtpError(ERR_FAIL_ERRNO, errno.EISDIR)
                self._not_the_log(path)
                path.unlink()
            elif op == OP_MKDIR:
                path.mkdir()
            elif op == OP_RMDIR:
                path.rmdir()
            elif op == OP_TRUNCATE:
                self._writable(root, path)
                os.truncate(path, offset)
            elif op == OP_RENAME:
                parts = data.split(b"\0")
                if len(parts) < 2 or not parts[1]:
                    raise FtpError(ERR_INVALID_DATA_SIZE)
                target = self._path(root, parts[1])
                self._not_the_log(path)
                self._not_the_log(target)
                path.rename(target)
            else:
                raise FtpError(ERR_UNKNOWN_COMMAND)
        except OSError as e:
            raise _os_error(e) from None
        return session, 0, b""

    # ------------------------------------------------------------------ paths
    def _path(self, root: Path, raw: bytes) -> Path:
        """A client path inside the tree ('/' is its root; '..' never leaves it)."""
        text = raw.decode("utf-8", errors="replace")
        if text.startswith("@"):  # PX4's virtual files (@PARAM/param.pck, @ROMFS): not offered
            raise FtpError(ERR_FILE_NOT_FOUND)
        rel = posixpath.normpath("/" + text).lstrip("/")
        return root / rel if rel else root

    def _readable(self, root: Path, path: Path) -> Path:
        real = Path(os.path.realpath(path))
        base = Path(os.path.realpath(root.parent.parent))  # the run directory
        if real != base and base not in real.parents:
            raise FtpError(ERR_FILE_PROTECTED)
        return real

    def _not_the_log(self, path: Path) -> None:
        """The flight log, which the logger writes, is not renamed, removed or replaced (as a link or a file)."""
        files = self.api.log_files
        logs = {Path(os.path.realpath(p)) for p, _size, _t in files.files()} if files is not None else set()
        if Path(os.path.realpath(path)) in logs or (path.suffix == ".ulg" and path.is_symlink()):
            raise FtpError(ERR_FILE_PROTECTED)

    def _writable(self, root: Path, path: Path) -> Path:
        real = self._readable(root, path)
        tree = Path(os.path.realpath(root))
        params = Path(os.path.realpath(root / "parameters.json"))
        if real != params and tree not in real.parents:
            raise FtpError(ERR_FILE_PROTECTED)  # the ULog, which the logger writes
        return real

    # ------------------------------------------------------------------ operations
    def _list(self, root: Path, data: bytes, offset: int) -> bytes:
        path = self._readable(root, self._path(root, data.split(b"\0", 1)[0]))
        try:
            names = sorted(os.listdir(path))
        except FileNotFoundError:
            raise FtpError(ERR_FILE_NOT_FOUND) from None
        except NotADirectoryError:
            raise FtpError(ERR_FAIL_ERRNO, errno.ENOTDIR) from None
        except OSError as e:
            raise _os_error(e) from None
        if offset >= len(names):
            raise FtpError(ERR_EOF)
        out = bytearray()
        for name in names[offset:]:
            try:
                st = (path / name).stat()
                if os.path.isdir(path / name):
                    entry = f"D{name}"
                else:
                    size = self._log_size(Path(os.path.realpath(path / name))) if name.endswith(".ulg") else None
                    entry = f"F{name}\t{st.st_size if size is None else size}"
            except OSError:
                entry = "S"  # a dangling link: skipped, as PX4 skips what it cannot show
            raw = entry.encode("utf-8") + b"\0"
            if len(out) + len(raw) > DATA_MAX:
                break
            out += raw
        return bytes(out)

    def _open(self, root: Path, op: int, data: bytes) -> tuple[int, int]:
        path = self._path(root, data.split(b"\0", 1)[0])
        try:
            if op == OP_OPEN_RO:
                real = self._readable(root, path)
                if real.is_dir():
                    raise FtpError(ERR_FAIL_ERRNO, errno.EISDIR)
                size = self._log_size(real)
                f: BinaryIO = real.open("rb")
                if size is None:
                    size = os.fstat(f.fileno()).st_size
            else:
                real = self._writable(root, path)
                if op == OP_CREATE:
                    f = real.open("w+b")
                else:
                    f = real.open("r+b") if real.exists() else real.open("w+b")
                size = os.fstat(f.fileno()).st_size
        except OSError as e:
            raise _os_error(e) from None
        if len(self._sessions) >= MAX_SESSIONS:
            idle = [k for k, s in self._sessions.items() if self._now - s.used_ns > SESSION_IDLE_NS]
            if not idle:
                f.close()
                raise FtpError(ERR_NO_SESSIONS)
            self._sessions.pop(idle[0]).f.close()  # a client that vanished mid-transfer
        mine = {sid for peer, sid in self._sessions if peer == self._peer}
        sid = min(set(range(MAX_SESSIONS)) - mine)  # 0 for a peer's first: MAVSDK assumes session 0
        self._sessions[(self._peer, sid)] = _Session(real, f, size, op != OP_OPEN_RO, self._now)
        return sid, size

    def _log_size(self, real: Path) -> int | None:
        """A flight log being written: flushed, and its size up to the last whole message."""
        files = self.api.log_files
        if files is None:
            return None
        for path, size, _t in files.files():
            if Path(os.path.realpath(path)) == real:
                return int(size)
        return None

    def _session(self, session: int) -> _Session:
        """The sender's session ``session`` (another peer's is not there for it: InvalidSession)."""
        s = self._sessions.get((self._peer, session))
        if s is None:
            raise FtpError(ERR_INVALID_SESSION)
        s.used_ns = self._now
        return s

    def _read(self, session: int, offset: int, n: int) -> bytes:
        s = self._session(session)
        if offset >= s.size:
            raise FtpError(ERR_EOF)
        try:
            s.f.seek(offset)
            return s.f.read(min(n, s.size - offset))
        except OSError as e:
            raise _os_error(e) from None

    def _burst(self, seq: int, session: int, offset: int) -> list[bytes]:
        chunk = self._read(session, offset, DATA_MAX * BURST)
        out = []
        parts = range(0, len(chunk), DATA_MAX)
        for k, i in enumerate(parts):
            body = chunk[i : i + DATA_MAX]
            done = 1 if k == len(parts) - 1 else 0
            out.append(self._pack(seq + 1 + k, session, OP_ACK, OP_BURST, done, offset + i, body))
        return out

    def _crc_request(self, root: Path, seq: int, data: bytes, origin: Origin) -> list[Out]:
        """CalcFileCRC32: at once for a file of at most ``CRC_CHUNK`` bytes, else over several ticks (a repeat
        of the request while it is worked out only updates the seq the answer carries)."""
        job = self._crc_jobs.get(self._peer)
        path = self._path(root, data.split(b"\0", 1)[0])
        try:
            real = self._readable(root, path)
            if job is not None and job.path == real:
                job.seq, job.origin = seq, origin
                return []
            f = real.open("rb")
        except OSError as e:
            raise _os_error(e) from None
        if job is not None:  # a new file asked for: the old one is given up
            job.f.close()
            del self._crc_jobs[self._peer]
        job = _CrcJob(origin, seq, real, f)
        try:
            block = f.read(CRC_CHUNK + 1)
        except OSError as e:
            f.close()
            raise _os_error(e) from None
        if len(block) <= CRC_CHUNK:
            f.close()
            reply = self._pack(seq + 1, 0, OP_ACK, OP_CRC32, 0, 0, struct.pack("<I", crc32_px4(block)))
            return [self._out(reply, origin)]
        job.crc = crc32_px4(block)
        self._crc_jobs[self._peer] = job
        return []


def nak(mav: mavlink2.MAVLink, m: MAVLinkMessage, origin: Origin) -> list[Out]:
    """A NAK for any request (FileNotFound for open, UnknownCommand otherwise): for vehicles that offer no MAVFTP."""
    payload = bytes(m.payload)
    if len(payload) < _HEADER.size:
        return []
    seq, session, opcode, _size, _req, _burst, _pad, _offset = _HEADER.unpack_from(payload)
    if opcode >= OP_ACK:  # a reply, not a request
        return []
    error = ERR_FILE_NOT_FOUND if opcode == OP_OPEN_RO else ERR_UNKNOWN_COMMAND
    reply = _HEADER.pack((seq + 1) & 0xFFFF, session, OP_NAK, 1, opcode, 0, 0, 0) + bytes([error])
    data = list(reply) + [0] * (251 - len(reply))
    return [Out(mav.file_transfer_protocol_encode(0, origin.sysid, origin.compid, data), origin)]
