"""Which MAVLink peers belong to the run: the kernel says which process owns the socket a datagram came from.

With signing on, a vehicle obeys signed frames from anyone and unsigned frames only from the run's own
processes — the missions ``harness run`` started (and what they start: ``mavsdk_server``), which are
unmodified scripts that know nothing of the key. A UDP datagram or TCP connection from loopback carries its
source address and port; ``/proc/net/{udp,tcp}{,6}`` maps the sockets that can send from that address (bound
to it, or to the wildcard address on its port) to inodes, and ``/proc/<pid>/fd`` says which processes hold
them. The peer is the run's when every one of those sockets is held by processes descending from the run's
main process. Never by port alone: a stranger can bind ``127.0.0.2`` on the port a mission holds on
``127.0.0.1``. A process outside the run (another user's, or the same user's but not started by this run) is
not trusted whatever address it uses. Every service (commands, parameters, missions, MAVFTP, the shell) is
behind this one check: an unsigned frame that fails it is dropped before it is decoded into a message.
Answers are cached per address for a few seconds.

Linux only (``/proc``); elsewhere nothing is trusted and every frame must be signed.
"""

from __future__ import annotations

import ipaddress
import os
import sys
from collections.abc import Iterable
from pathlib import Path

from harness.autopilot.mavlink.codec import SigningConfig
from harness.core.clock import NS_PER_S, real_monotonic_ns
from harness.core.secrets import read_signing_key

Address = tuple[str, int]

TRUSTED_TTL_S = 10.0
REFUSED_TTL_S = 2.0
_LOOPBACK_V6 = ("::1", "::ffff:127.")


def _is_loopback(host: str) -> bool:
    return host.startswith("127.") or host.startswith(_LOOPBACK_V6)


def _proc_ip(hexaddr: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address:
    """An address as ``/proc/net/{udp,tcp}{,6}`` writes it: 32-bit words in host byte order, in hex."""
    raw = bytes.fromhex(hexaddr)
    words = b"".join(int.from_bytes(raw[i : i + 4], sys.byteorder).to_bytes(4, "big") for i in range(0, len(raw), 4))
    ip = ipaddress.ip_address(words)
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        return ip.ipv4_mapped
    return ip


def _peer_ip(host: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    try:
        ip = ipaddress.ip_address(host.split("%", 1)[0])
    except ValueError:
        return None
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        return ip.ipv4_mapped
    return ip


def socket_inodes(proto: str, addr: Address, proc: Path = Path("/proc")) -> set[str]:
    """Inodes of the ``proto`` ("udp" or "tcp") sockets that can send from ``addr`` (host, port): bound to that
    address and port, or to the wildcard address on that port (IPv4 and IPv6 tables).

    A port alone says nothing: another process may bind ``127.0.0.2`` on the port a mission holds on
    ``127.0.0.1`` (ports are world-readable here). The caller trusts ``addr`` only when every one of these
    sockets is the run's (a wildcard socket of a stranger on the same port makes it untrusted too)."""
    want = _peer_ip(addr[0])
    found: set[str] = set()
    if want is None:
        return found
    for table in (proto, proto + "6"):
        try:
            lines = (proc / "net" / table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if len(fields) <= 9 or fields[9] == "0":  # inode 0: a TIME_WAIT leftover nobody holds
                continue
            host, _, port = fields[1].rpartition(":")
            try:
                if int(port, 16) != addr[1]:
                    continue
                ip = _proc_ip(host)
            except ValueError:
                continue
            if ip == want or ip.is_unspecified:
                found.add(fields[9])
    return found


def udp_bound(proc: Path = Path("/proc")) -> set[Address] | None:
    """Every (address, port) a UDP socket on this machine is bound to (the wildcard as "0.0.0.0" / "::");
    None when ``/proc`` cannot say (not Linux)."""
    found: set[Address] = set()
    read_any = False
    for table in ("udp", "udp6"):
        try:
            lines = (proc / "net" / table).read_text().splitlines()[1:]
        except OSError:
            continue
        read_any = True
        for line in lines:
            fields = line.split()
            if len(fields) < 2:
                continue
            host, _, port = fields[1].rpartition(":")
            try:
                found.add((str(_proc_ip(host)), int(port, 16)))
            except ValueError:
                continue
    return found if read_any else None


def _children(pid: int, proc: Path) -> list[int]:
    """Direct children of ``pid`` (every thread's ``children`` file: a child belongs to the thread that forked it)."""
    out: list[int] = []
    try:
        tids = os.listdir(proc / str(pid) / "task")
    except OSError:
        return out
    for tid in tids:
        try:
            out.extend(int(c) for c in (proc / str(pid) / "task" / tid / "children").read_text().split())
        except (OSError, ValueError):
            continue
    return out


def descendants(root: int, proc: Path = Path("/proc"), *, quick: bool = False) -> list[int]:
    """Every live process below ``root`` (children, their children, ...), not ``root`` itself.

    ``quick``: walk down from ``root`` through the ``children`` files, reading a handful of files instead of
    every process's ``stat`` (~1 ms each on a busy machine) — but the kernel documents those files as
    unreliable while processes fork, and some sandboxes leave children out: a miss must be checked again with
    the full scan."""
    if quick:
        out: list[int] = []
        todo = _children(root, proc)
        while todo:
            pid = todo.pop()
            out.append(pid)
            todo.extend(_children(pid, proc))
        return out
    children: dict[int, list[int]] = {}
    for entry in os.listdir(proc):
        if not entry.isdigit():
            continue
        try:
            fields = (proc / entry / "stat").read_text().rsplit(")", 1)[-1].split()
        except OSError:
            continue
        if len(fields) > 1:
            children.setdefault(int(fields[1]), []).append(int(entry))
    found: list[int] = []
    todo = list(children.get(root, ()))
    while todo:
        pid = todo.pop()
        found.append(pid)
        todo.extend(children.get(pid, ()))
    return found


def owns_all(pids: Iterable[int], inodes: set[str], proc: Path = Path("/proc")) -> bool:
    """Whether ``pids`` between them hold every socket of ``inodes`` (none: False)."""
    links = {f"socket:[{i}]" for i in inodes}
    for pid in pids:
        fd_dir = proc / str(pid) / "fd"
        try:
            fds = os.listdir(fd_dir)
        except OSError:
            continue
        for fd in fds:
            try:
                links.discard(os.readlink(fd_dir / fd))
            except OSError:
                continue
            if not links:
                return bool(inodes)
    return False


class RunLocalPeers:
    """``trusted(tcp, addr)``: whether the loopback peer ``addr`` is a socket of a process under ``root_pid``."""

    def __init__(self, root_pid: int, proc: Path = Path("/proc")) -> None:
        self.root_pid = root_pid
        self._proc = proc
        self._cache: dict[tuple[bool, Address], tuple[bool, int]] = {}
        self._trusted_inodes: set[str] = set()

    def __call__(self, tcp: bool, addr: Address) -> bool:
        return self.trusted(tcp, addr)

    def trusted(self, tcp: bool, addr: Address) -> bool:
        if not _is_loopback(addr[0]):
            return False
        now = real_monotonic_ns()
        key = (tcp, addr)
        cached = self._cache.get(key)
        if cached is not None and cached[1] > now:
            return cached[0]
        inodes = socket_inodes("tcp" if tcp else "udp", addr, self._proc)
        if inodes and inodes <= self._trusted_inodes:  # the same sockets as before: no need to find their owner
            verdict = True
        else:
            verdict = bool(inodes) and (
                owns_all(descendants(self.root_pid, self._proc, quick=True), inodes, self._proc)
                or owns_all(descendants(self.root_pid, self._proc), inodes, self._proc)
            )
            if verdict:
                self._trusted_inodes |= inodes
        ttl = TRUSTED_TTL_S if verdict else REFUSED_TTL_S
        if len(self._cache) > 4096:  # a flood of source ports cannot grow it without bound
            self._cache.clear()
            self._trusted_inodes.clear()
        self._cache[key] = (verdict, now + int(ttl * NS_PER_S))
        return verdict


def run_signing(key_file: Path | None, run_pid: int) -> tuple[SigningConfig | None, RunLocalPeers | None]:
    """A run's signing configuration (None without a key file) and who may still send unsigned frames: the
    processes under ``run_pid``."""
    if key_file is None:
        return None, None
    return SigningConfig(read_signing_key(key_file, "signing_key_file")), RunLocalPeers(run_pid)
