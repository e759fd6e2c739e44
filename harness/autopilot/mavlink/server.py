"""The MAVLink server of one vehicle: the pure services behind its UDP links, served on the wall clock.

It never waits for the simulation: it reads the autopilot through its thread-safe API (``state()`` is a
snapshot of the last tick), answers within milliseconds, sends heartbeats at >= 1 Hz of wall time while
the simulation is paused or slow, and streams telemetry at the faster of the sim and the wall rate.
Bad input is counted, logged at debug level, and never stops the server.

A :class:`~harness.autopilot.mavlink.hub.MavlinkHub` thread drives it on the wall clock (one hub serves
every vehicle of a process): ``receive`` on a datagram, ``service`` when ``next_wake_ns`` is reached. The
autopilot's stepping thread calls ``service`` too, through the autopilot's bell: when sim time reaches the
next sim-rate stream, or mode, arming, texts or mission progress changed. So sim-rate telemetry goes out in
lockstep, at the tick it is due, at any speed (a wall-clock thread could not keep up at x50: it sent one
ATTITUDE per 1.2 s of sim time instead of ten per second). A lock per server serialises the two threads.
``start()`` gives a server a hub of its own.

    server = MavlinkServer(autopilot, vehicle=0, ports=PortsConfig(...), signing=None)
    server.start() ... server.counters() ... server.stop()
"""

from __future__ import annotations

import copy
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import FlightMode, GeoPoint, Result, Severity, VehicleState
from harness.autopilot.firmware import Firmware
from harness.autopilot.mavlink import ftp
from harness.autopilot.mavlink.codec import Codec, FrameStatus, SigningConfig
from harness.autopilot.mavlink.commands import CommandIn, CommandService
from harness.autopilot.mavlink.datalink import DataLinkMonitor
from harness.autopilot.mavlink.heartbeat import HeartbeatSchedule
from harness.autopilot.mavlink.hub import MavlinkHub
from harness.autopilot.mavlink.logs import LOG_IDS, LogService
from harness.autopilot.mavlink.messages import MAVLinkMessage, Origin, Out, statustext
from harness.autopilot.mavlink.mission import MissionService, ProgressTracker
from harness.autopilot.mavlink.offboard import handle_setpoint
from harness.autopilot.mavlink.parameters import ParamService
from harness.autopilot.mavlink.personality import make_dialect
from harness.autopilot.mavlink.pilot import PILOT_IDS, handle_pilot
from harness.autopilot.mavlink.tcp import TcpLink
from harness.autopilot.mavlink.telemetry import BUILDERS, StreamScheduler, mission_current, mission_state_of
from harness.autopilot.mavlink.transport import GREET_NS, Address, Link, PortsConfig, UdpLink, pack_frames
from harness.autopilot.services import System
from harness.core.clock import WALL, Clock
from harness.core.endpoints import SETTLE_PREFIX, sysid

log = logging.getLogger(__name__)

_M = mavlink2
_PARAM_IDS = {_M.MAVLINK_MSG_ID_PARAM_REQUEST_LIST, _M.MAVLINK_MSG_ID_PARAM_REQUEST_READ, _M.MAVLINK_MSG_ID_PARAM_SET}
_MISSION_IDS = {
    _M.MAVLINK_MSG_ID_MISSION_COUNT,
    _M.MAVLINK_MSG_ID_MISSION_ITEM_INT,
    _M.MAVLINK_MSG_ID_MISSION_ITEM,
    _M.MAVLINK_MSG_ID_MISSION_REQUEST_LIST,
    _M.MAVLINK_MSG_ID_MISSION_REQUEST_INT,
    _M.MAVLINK_MSG_ID_MISSION_REQUEST,
    _M.MAVLINK_MSG_ID_MISSION_ACK,
    _M.MAVLINK_MSG_ID_MISSION_CLEAR_ALL,
    _M.MAVLINK_MSG_ID_MISSION_SET_CURRENT,
}
_SETPOINT_IDS = {
    _M.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED,
    _M.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT,
    _M.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET,
}
_TEXT_REPEAT_NS = 2_000_000_000
_POLL_NS = 10_000_000
"""Without a bell (a ``System`` whose ``bell`` is None), sim-rate streams are checked every 10 ms
of wall time while sim time moves ..."""
_POLL_PAUSED_NS = 100_000_000
"""... and every 100 ms while it stands still."""
_SAFETY_NS = 1_000_000_000
"""With a bell, the server is still serviced at least once a second (data-link loss, home at first fix)."""
_PARAM_PACE_NS = 2_000_000
"""A parameter list download goes out in batches every 2 ms (``ParamService.per_tick`` per batch)."""
_NEVER = 1 << 62


@dataclass
class MavlinkCounters:
    datagrams_rx: int = 0
    frames_rx: int = 0
    """Well-formed frames accepted (signed correctly when signing is on)."""
    malformed: int = 0
    unknown_msg: int = 0
    refused_unsigned: int = 0
    refused_bad_signature: int = 0
    not_for_us: int = 0
    handler_errors: int = 0
    setpoints_refused: int = 0
    frames_tx: int = 0
    send_errors: int = 0
    commands: dict[str, int] = field(default_factory=dict)
    """By MAV_RESULT name (ACCEPTED, DENIED, UNSUPPORTED, ...), retransmissions included."""
    commands_by_id: dict[int, dict[str, int]] = field(default_factory=dict)


DATAGRAMS_PER_LOOP = 8
"""Datagrams one autopilot loop (a tick, 4 ms at 250 Hz) handles at most; later ones wait for the next loop, as a
flight stack's MAVLink receiver handles what came in once per loop. A client that answers every answer at once
(a COMMAND_ACK listener that sends the next command) then goes on at that rate in sim time instead of holding
phase 0 forever; a mission upload or a burst of setpoints is far below it. Counted by the loop's sim time, so
the same messages are handled in the same loop at any pace."""


RECEIVE_BUDGET_NS = 20_000_000
"""Wall time one ``receive`` spends on datagrams before it lets the hub service what is due (heartbeats,
streams): a client flooding the vehicle (shell, MAVFTP, commands) delays the others' heartbeats by about
this much, not by as long as the flood lasts. What is left stays in the socket, in order (a mission's settle
is answered only after everything it sent before)."""


class MavlinkServer:
    """PX4-dialect MAVLink endpoint of one vehicle (system id ``sysid(vehicle)``: ``vehicle + 1`` up to 244 vehicles; component 1).

    ``tap`` is called (on the server thread) with every frame sent and every valid frame received: the
    tlog writer. ``clock``: the wall clock its timers, heartbeats and signing timestamps run on (its hub's).
    ``home_on_first_fix``: see ``_set_home_at_first_fix``. ``firmware``: the personality it presents
    (``personality.py``); the services see the autopilot through its dialect (``self.api``).
    """

    def __init__(
        self,
        autopilot: System,
        vehicle: int,
        ports: PortsConfig | None = None,
        signing: SigningConfig | None = None,
        *,
        clock: Clock = WALL,
        tap: Callable[[bytes], None] | None = None,
        home_on_first_fix: bool = True,
        firmware: Firmware = Firmware.PX4,
        trust_unsigned: Callable[[bool, tuple[str, int]], bool] | None = None,
    ) -> None:
        self.firmware = firmware
        self._trust_unsigned = trust_unsigned
        """With signing: whether an unsigned frame from (is TCP, address) is obeyed all the same (``runlocal.py``)."""
        self.dialect = make_dialect(firmware, autopilot, sysid(vehicle))
        autopilot = self.dialect.api
        self.api = autopilot
        self.vehicle = vehicle
        self.sysid = sysid(vehicle)
        self.compid = 1
        self.ports = ports or PortsConfig()
        self.clock = clock
        self._wall_ns = clock.now_ns
        self._tap = tap
        self._home_on_first_fix = home_on_first_fix
        self._home_try_ns: int | None = None
        self._stepping = False
        self._first_t_ns: int | None = None
        self._sim_sent_told = 0
        """``sim_sent()`` at the last ``sent_to_missions()``."""
        """True while the autopilot's stepping thread services this server (the bell), at sim time."""
        self.codec = Codec(self.sysid, self.compid, signing, clock.unix_ns)
        mav = self.codec.mav
        self.components = dict(self.dialect.components)
        """The vehicle's other components (PX4: camera 100, winch 169), each framed by an encoder of its own."""
        self._component_codecs: dict[int, Codec] = {}
        for cid, component in self.components.items():
            self._component_codecs[cid] = Codec(self.sysid, cid, signing, clock.unix_ns)
            component.bind_component(self._component_codecs[cid].mav)
        self.links: list[Link] = [UdpLink(cfg) for cfg in self.ports.links(vehicle)]
        tcp = self.ports.tcp_local(vehicle)
        if tcp is not None:
            try:
                self.links.append(TcpLink("tcp", tcp, sim_clients=self.ports.tcp_sim_clients))
            except Exception:
                for lk in self.links:
                    lk.close()
                raise
        dialect = self.dialect
        self.builders = {**BUILDERS, **dialect.builders}
        self.streams = StreamScheduler(defaults=dict(dialect.stream_defaults), builders=self.builders)
        self.heartbeat = HeartbeatSchedule()
        self.params = ParamService(autopilot, mav, bytewise=dialect.param_bytewise)
        self.missions = MissionService(
            autopilot, mav, float_form=dialect.mission_float_form, check_item=dialect.check_mission_item
        )
        self.logs = LogService(autopilot, mav)
        self.commands = CommandService(autopilot, self._request_message, self.streams.set_interval)
        self.commands.override(dialect.command_handlers())
        self._progress = ProgressTracker()
        self.datalink = DataLinkMonitor(autopilot)
        self._counters = MavlinkCounters()
        self._counter_lock = threading.Lock()
        self._texts_sent: dict[str, int] = {}
        self._errors_logged: set[str] = set()
        self._chunk_id = 0
        self._t_ns = 0
        self._sim_moving = True
        self._home: GeoPoint | None = None
        self._hub: MavlinkHub | None = None
        self._own_hub = False
        self._lock = threading.Lock()
        """Serialises the hub thread (datagrams, wall-clock deadlines) and the stepping thread (the bell)."""
        self._ring_at: Callable[[int], None] | None = None
        self._loop_t = -1
        self._loop_datagrams = 0
        self._deferred: list[tuple[int, bytes, tuple[str, int]]] = []
        """What came after this loop's share: handled at the next step (``DATAGRAMS_PER_LOOP``)."""
        self.next_wake_ns = 0
        """Wall time (monotonic ns) at which the hub must call :meth:`service` at the latest."""
        dialect.bind(self, mav, self.sysid)

    # ------------------------------------------------------------------ public
    def start(self) -> MavlinkServer:
        """Serve on a thread of its own (a hub with just this server)."""
        if self._hub is not None:
            raise RuntimeError("MavlinkServer already started")
        hub = MavlinkHub(name=f"mavlink-{self.vehicle}", clock=self.clock)
        hub.add(self)
        hub.start()
        self._own_hub = True
        return self

    @property
    def alive(self) -> bool:
        """Whether a hub thread is serving this server."""
        return self._hub is not None and self._hub.alive

    def attached(self, hub: MavlinkHub) -> None:
        """Called by ``hub`` when it takes this server: hook the autopilot's bell to it (if it has one)."""
        self._hub = hub
        bell = self.api.bell
        if bell is not None:
            bell.attach(self._bell)
            self._ring_at = bell.ring_at
        self.next_wake_ns = 0

    def stop(self, timeout_s: float = 2.0) -> None:
        hub = self._hub
        if hub is not None:
            if self._own_hub:
                hub.stop(timeout_s)
            else:
                hub.remove(self)
        for link in self.links:
            link.close()
        self.dialect.close()  # after the hub let go of this server: nothing else touches the dialect now

    def close(self) -> None:
        """Same as ``stop()`` (the autopilot host's attach hook closes what it attached)."""
        self.stop()

    def __enter__(self) -> MavlinkServer:
        return self.start()

    def __exit__(self, *_exc: object) -> None:
        self.stop()

    def local_address(self, link: str) -> tuple[str, int]:
        """The bound address of link ``'api'`` or ``'gcs'`` (useful with port 0)."""
        for lk in self.links:
            if lk.name == link:
                return lk.local_address
        raise KeyError(f"no MAVLink link named {link!r} (have {[lk.name for lk in self.links]})")

    # ------------------------------------------------------------------ for the dialect (server thread)
    @property
    def mav(self) -> mavlink2.MAVLink:
        return self.codec.mav

    def say(self, severity: Severity, text: str, now: int) -> None:
        self._say(severity, text, now)

    def link_name(self, link: int) -> str:
        return self.links[link].name

    def counters(self) -> MavlinkCounters:
        with self._counter_lock:
            c = copy.deepcopy(self._counters)
        c.send_errors = sum(lk.send_errors for lk in self.links)
        return c

    # ------------------------------------------------------------------ driven by the hub
    def receive(self, link: int, now: int) -> None:
        """Datagrams are waiting on ``links[link]``: handle them (hub thread)."""
        with self._lock:
            start = self._wall_ns()
            try:
                for data, addr in self.links[link].receive(512):
                    self._on_datagram(link, data, addr, now)
                    if self._wall_ns() - start > RECEIVE_BUDGET_NS:
                        break  # the rest waits in the socket, in order: heartbeats and streams go out first
            except Exception as e:  # never let one bad datagram end the thread
                self._count("handler_errors")
                self._log_once(e, "receive")

    def _bell(self) -> None:
        """The autopilot's stepping thread, at a sim time something is due: sim-rate work happens here."""
        with self._lock:
            self._stepping = True
            try:
                if self._deferred:
                    self._handle_deferred(self._wall_ns())
                self._service(self._wall_ns())
            finally:
                self._stepping = False

    def service(self, now: int) -> None:
        """Everything periodic that is due (telemetry, heartbeat, texts, paced transfers); then plan the next
        wake-up: a wall time for the hub, a sim time for the autopilot's bell (hub or stepping thread)."""
        with self._lock:
            self._service(now)

    def _service(self, now: int) -> None:
        if self._deferred and not self._stepping and not self._sim_peers():
            # the peers on sim time are gone (a mission's TCP connection closed): nothing waits for a step now.
            # Never on a wall-clock limit while they are there: a phase 0 that takes long on a loaded machine
            # would let their datagrams run a loop early (a mission upload a tick early, another flight)
            waiting, self._deferred = self._deferred, []
            for k, data, addr in waiting:
                self._handle(k, data, addr, now)
        sim_peers = self._sim_peers()  # only a link's receive() adds one: the same for the rest of this service
        try:
            self._tick(now, sim_peers)
            for k, link in enumerate(self.links):  # a mission's MAVSDK port, announced: greet it until it answers
                for addr in link.greetings(now):
                    self._send(
                        Out(self.dialect.heartbeat(self.codec.mav, self.api.telemetry.state()), Origin(k, addr, 0, 0)),
                        now,
                    )
        except Exception as e:
            self._count("handler_errors")
            self._log_once(e, "service")
        retry = self.missions.next_retry_ns() or _NEVER
        wake = min(
            self.heartbeat.next_due_ns(), self.streams.next_due_wall_ns() or _NEVER, _NEVER if sim_peers else retry
        )
        if self.params.busy or self.dialect.busy:
            wake = min(wake, now + _PARAM_PACE_NS)
        if any(link.greeting for link in self.links):
            wake = min(wake, now + GREET_NS)
        if self._ring_at is None:
            wake = min(wake, now + (_POLL_NS if self._sim_moving else _POLL_PAUSED_NS))
        else:
            wake = min(wake, now + _SAFETY_NS)
            self._ring_at(
                min(
                    self.streams.next_due_sim_ns() or _NEVER,
                    self.heartbeat.next_due_sim_ns() or _NEVER,
                    self._t_ns + 1 if self._deferred else _NEVER,
                    retry if sim_peers else _NEVER,
                )
            )
        self.next_wake_ns = wake

    def _log_once(self, e: Exception, what: str) -> None:
        """A traceback the first time an error of this kind happens, debug lines after that."""
        key = f"{what}: {type(e).__name__}"
        if key in self._errors_logged:
            log.debug("vehicle %d: %s failed again: %s", self.vehicle, what, e)
            return
        self._errors_logged.add(key)
        log.exception(
            "vehicle %d: MAVLink %s failed (further failures of this kind logged at debug)", self.vehicle, what
        )

    def _count(self, name: str, n: int = 1) -> None:
        with self._counter_lock:
            setattr(self._counters, name, getattr(self._counters, name) + n)

    # ------------------------------------------------------------------ receive
    def _on_datagram(self, link: int, data: bytes, addr: tuple[str, int], now: int) -> None:
        if data.startswith(SETTLE_PREFIX):
            # a mission's runtime asks whether all it sent before is handled: yes (one socket, in order; what
            # came after this loop's share waits for the next step, which is as sure); what that caused (a
            # forced heartbeat, a STATUSTEXT, a due message) goes out before the answer
            self._drain_tcp(now)  # its MAVLink may have come over TCP (SERIAL0) instead
            self._service(now)
            while self.params.busy:  # a parameter list it asked for goes out now, not paced on the wall clock
                self._send_all(self.params.tick(), now)
            self.links[link].send(data, addr)
            return
        if self.links[link].is_sim_peer(addr) and (self._deferred or not self._in_budget()):
            self._deferred.append((link, data, addr))
            if self._ring_at is not None:
                self._ring_at(self._t_ns + 1)
            return
        self._handle(link, data, addr, now)

    def _handle(self, link: int, data: bytes, addr: tuple[str, int], now: int) -> None:
        self._count("datagrams_rx")
        for d in self.codec.decode(data):
            if d.status is FrameStatus.UNSIGNED and self._trusted(link, addr):
                d.status = FrameStatus.OK  # a process of this run (its mission): obeyed unsigned
            if d.status is FrameStatus.MALFORMED:
                self._count("malformed")
            elif d.status is FrameStatus.UNKNOWN:
                self._count("unknown_msg")
                if self._tap is not None and d.message is not None:  # the tlog keeps every frame, known or not
                    self._tap(bytes(d.message.get_msgbuf()))
            elif d.status is FrameStatus.UNSIGNED:
                self._count("refused_unsigned")
            elif d.status is FrameStatus.BAD_SIGNATURE:
                self._count("refused_bad_signature")
            elif d.message is not None:
                self._count("frames_rx")
                m = d.message
                if self.links[link].heard(addr, now) and (link == 0 or self.links[link].name == "tcp"):
                    # a new client on the API link (MAVSDK connecting out) hears from us at once, not at the
                    # next heartbeat: it discovers the vehicle while a starting mission holds the sim clock
                    hb = self.dialect.heartbeat(self.codec.mav, self.api.telemetry.state())
                    self._send(Out(hb, Origin(link, addr, 0, 0)), now)
                if self._tap is not None:
                    self._tap(bytes(m.get_msgbuf()))
                origin = Origin(link, addr, m.get_srcSystem(), m.get_srcComponent())
                try:
                    self._dispatch_dialect(m, origin, now)
                except Exception as e:
                    self._count("handler_errors")
                    self._log_once(e, f"handling {m.get_type()}")

    def _loop_t_ns(self) -> int:
        return max(self._t_ns, self.api.telemetry.state().t_ns)

    def sim_sent(self) -> int:
        """MAVLink sent so far to peers on sim time (the run's missions), by any thread."""
        return sum(link.sim_sent for link in self.links)

    def sent_to_missions(self) -> bool:
        """Whether this vehicle sent MAVLink to peers on sim time since the last call: its host tells the channel at
        each tick with phases (END-TICK-AC ``mavlink``), so a mission waiting for it is woken. One caller: the host."""
        n = self.sim_sent()
        moved, self._sim_sent_told = n != self._sim_sent_told, n
        return moved

    def _sim_peers(self) -> bool:
        """Whether a peer that lives on sim time (a mission) talks to this vehicle."""
        return any(link.has_sim_peers for link in self.links)

    def _peer_now(self, now: int) -> int:
        """The clock of timeouts that concern peers (mission-upload retries, data-link loss): sim time while a
        mission talks to this vehicle (it answers only in phase 0, however long the machine takes between two
        phases), the wall clock for ground stations alone."""
        return self._loop_t_ns() if self._sim_peers() else now

    def _in_budget(self) -> bool:
        """Count one datagram against this loop's share (``DATAGRAMS_PER_LOOP``); False once it is used up.

        Only for what a peer that lives on sim time (a mission) sends: it alone can hold phase 0 with a
        ping-pong, and its runs step the vehicle. A ground station (``harness sitl``, a paused or idle vehicle,
        QGroundControl beside a run's missions) is answered at once, whatever it sends."""
        if not self._sim_peers():
            return True
        t = self._loop_t_ns()
        if t != self._loop_t:
            self._loop_t, self._loop_datagrams = t, 0
        if self._loop_datagrams >= DATAGRAMS_PER_LOOP:
            return False
        self._loop_datagrams += 1
        return True

    def _handle_deferred(self, now: int) -> None:
        """The next step (the bell): what waited for it is handled first, in the order it came."""
        deferred, self._deferred = self._deferred, []
        for k, (link, data, addr) in enumerate(deferred):
            if not self._in_budget():
                self._deferred = deferred[k:]
                return
            self._handle(link, data, addr, now)

    def _trusted(self, link: int, addr: tuple[str, int]) -> bool:
        trust = self._trust_unsigned
        return trust is not None and trust(isinstance(self.links[link], TcpLink), addr)

    def _drain_tcp(self, now: int) -> None:
        """Handle every frame already sent to the TCP links (the settle datagram comes over UDP)."""
        for i, lk in enumerate(self.links):
            if isinstance(lk, TcpLink):
                lk.drain()
                for data, addr in lk.receive(512):
                    self._on_datagram(i, data, addr, now)

    def _for_us(self, m: MAVLinkMessage) -> bool:
        if getattr(m, "target_network", 0) != 0:
            return False
        ts = getattr(m, "target_system", 0)
        tc = getattr(m, "target_component", 0)
        return ts in (0, self.sysid) and tc in (0, self.compid)

    def _dispatch_dialect(self, m: MAVLinkMessage, origin: Origin, now: int) -> None:
        """The firmware's own handling first (messages addressed to us), then the generic services; what is
        addressed to another component of the vehicle (the camera, the winch) goes to it."""
        component = self.components.get(getattr(m, "target_component", -1)) if self.components else None
        if component is not None:
            if getattr(m, "target_system", 0) in (0, self.sysid):
                self._send_all(component.handle_component(m, origin), now)
            return
        if m.get_msgId() != _M.MAVLINK_MSG_ID_HEARTBEAT and self._for_us(m):
            outs = self.dialect.handle(m, origin, now)
            if outs is not None:
                self._send_all(outs, now)
                return
        self._dispatch(m, origin, now)

    def _dispatch(self, m: MAVLinkMessage, origin: Origin, now: int) -> None:
        mid = m.get_msgId()
        if mid == _M.MAVLINK_MSG_ID_HEARTBEAT:
            if m.type == _M.MAV_TYPE_GCS:
                self.datalink.heard_gcs(self._peer_now(now))
            return
        if not self._for_us(m):
            self._count("not_for_us")
            return
        if mid in (_M.MAVLINK_MSG_ID_COMMAND_LONG, _M.MAVLINK_MSG_ID_COMMAND_INT):
            self._command(m, origin, now)
        elif mid in _SETPOINT_IDS:
            r = handle_setpoint(self.api, m)
            if not r.ok:
                self._count("setpoints_refused")
                self._say(Severity.WARNING, r.reason, now)
        elif mid in _PARAM_IDS:
            outs, refusal = self.params.handle(m, origin)
            self._send_all(outs, now)
            if refusal is not None:
                self._say(Severity.WARNING, refusal.reason, now)
        elif mid in _MISSION_IDS:
            self._send_all(self.missions.handle(m, origin, self._peer_now(now)), now)
            self._mission_refusals(now)
        elif mid in PILOT_IDS:
            r = handle_pilot(self.api, m, self.sysid)
            if not r.ok:
                self._count("setpoints_refused")
                self._say(Severity.WARNING, r.reason, now)
        elif mid in LOG_IDS:
            self._send_all(self.logs.handle(m, origin), now)
        elif mid == _M.MAVLINK_MSG_ID_SET_MODE:
            custom = m.custom_mode
            r = self.commands.set_mode_px4(m.base_mode, (custom >> 16) & 0xFF, (custom >> 24) & 0xFF)
            if r.ok:
                self.heartbeat.force()
            elif r.reason:
                self._say(Severity.WARNING, r.reason, now)
        elif mid == _M.MAVLINK_MSG_ID_PING and m.target_system == 0:
            mav = self.codec.mav
            self._send(Out(mav.ping_encode(m.time_usec, m.seq, origin.sysid, origin.compid), origin), now)
        elif mid == _M.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL:
            self._send_all(ftp.nak(self.codec.mav, m, origin), now)
        elif mid == _M.MAVLINK_MSG_ID_TIMESYNC and m.tc1 == 0:
            # tc1 on the time base of every time_boot_ms and time_usec this vehicle sends: sim time since boot
            # (the last step's), as PX4 answers with its own boot time — never the host's uptime
            t_ns = max(self._t_ns, self.api.telemetry.state().t_ns)
            self._send(Out(self.codec.mav.timesync_encode(t_ns, m.ts1), origin), now)

    def _command(self, m: MAVLinkMessage, origin: Origin, now: int) -> None:
        cmd = CommandIn.from_message(m)
        # a mission's retransmission is told from a repeat by its own clock, sim time (at max speed a repeat 2 s of
        # sim apart came 0.1 s of wall time apart and was taken for one), a ground station's by the wall clock
        on_sim = self.links[origin.link].is_sim_peer(origin.addr)
        sender = (origin.link, origin.addr, origin.sysid, origin.compid)
        outcome = self.commands.handle(cmd, sender, self._loop_t_ns() if on_sim else now)
        r = outcome.result
        mav = self.codec.mav
        ack = mav.command_ack_encode(cmd.command, int(r.result), 0, 0, origin.sysid, origin.compid)
        self._send(Out(ack, origin), now)
        for msg in outcome.followups:
            self._send(Out(msg, origin), now)
        if outcome.mode_or_arming_changed:
            self.heartbeat.force()
        if r.result != Result.ACCEPTED and r.reason and not outcome.replayed:
            self._say(Severity.WARNING if r.result != Result.DENIED else Severity.CRITICAL, r.reason, now)
        elif outcome.notice and not outcome.replayed:
            self._say(Severity.CRITICAL, outcome.notice, now)
        name = r.result.name
        with self._counter_lock:
            c = self._counters
            c.commands[name] = c.commands.get(name, 0) + 1
            per = c.commands_by_id.setdefault(cmd.command, {})
            per[name] = per.get(name, 0) + 1

    def _request_message(self, msg_id: int) -> MAVLinkMessage | str | None:
        mav = self.codec.mav
        if msg_id == _M.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return self.dialect.autopilot_version(mav, self.sysid)
        builder = self.builders.get(msg_id)
        if builder is None:
            return None
        msg = builder(mav, self.api.telemetry.state(), self._boot_ms())
        return "" if msg is None else msg  # no home yet: TEMPORARILY_REJECTED, no STATUSTEXT (MAVSDK polls)

    # ------------------------------------------------------------------ periodic
    def _boot_ms(self) -> int:
        return (self._t_ns // 1_000_000) & 0xFFFFFFFF

    def _tick(self, now: int, sim_peers: bool) -> None:
        """One instant's messages. ``sim_peers``: :meth:`_sim_peers`, which a tick does not change; the peers'
        clock (:meth:`_peer_now`) is read once, after sim time has been brought up to the state's."""
        state = self.api.telemetry.state()
        if self._first_t_ns is None:
            self._first_t_ns = state.t_ns
        # decided at sim time: by the stepping thread (the bell), or by the hub when nobody steps the autopilot
        # (it has not moved since this server started); never by the hub during a long phase of a mission
        at_sim_time = self._stepping or self._ring_at is None or state.t_ns == self._first_t_ns
        if self._home_on_first_fix and state.home is None and at_sim_time and self._set_home_at_first_fix(state):
            state = self.api.telemetry.state()
        self._sim_moving = state.t_ns > self._t_ns
        self._t_ns = max(self._t_ns, state.t_ns)
        mav = self.codec.mav
        outs: list[Out] = []
        peer_now = self._t_ns if sim_peers else now  # _peer_now(now): _t_ns is at least the state's time now
        if self.heartbeat.due(now, state, sim_peers):
            outs.append(Out(self.dialect.heartbeat(mav, state), wall_clock=self.heartbeat.by_wall))
            for cid, component in self.components.items():
                hb = component.heartbeat()
                if hb is not None:
                    outs.append(Out(hb, wall_clock=self.heartbeat.by_wall, compid=cid))
        t_ms = self._boot_ms()
        for msg_id, by_wall in self.streams.due_by_clock(now, self._t_ns, sim_peers):
            msg = self.builders[msg_id](mav, state, t_ms)
            if msg is not None:
                outs.append(Out(msg, wall_clock=by_wall))
        if state.home is not None and state.home != self._home:
            self._home = state.home
            home = BUILDERS[_M.MAVLINK_MSG_ID_HOME_POSITION](mav, state, t_ms)
            if home is not None:
                outs.append(Out(home))
        in_mission = state.mode is FlightMode.MISSION
        m = state.mission
        if self._progress.changed(m.current_seq, m.count, mission_state_of(state), in_mission):
            outs.append(Out(mission_current(mav, state, t_ms)))
        for reached in self.api.telemetry.pop_mission_reached():
            outs.append(Out(mav.mission_item_reached_encode(reached.seq & 0xFFFF)))
        outs += self.dialect.tick(state, peer_now)
        self._send_all(outs, now)
        lost = self.datalink.check(state, peer_now)
        if lost:
            self._say(Severity.CRITICAL, lost, now)
        for text in self.api.telemetry.pop_status_texts():
            self._say(text.severity, text.text, now)
        self._send_all(self.params.tick(), now)
        self._send_all(self.missions.tick(peer_now), now)
        self._mission_refusals(now)

    def _set_home_at_first_fix(self, state: VehicleState) -> bool:
        """Adapter: PX4 sets home as soon as the global position is good, before arming; MAVSDK scripts wait
        for ``is_home_position_ok`` before they arm. The flight core sets home only when arming, so this
        asks it to set home here once GPS and the position estimate are good (retried every second of sim time),
        at a sim time (the autopilot's bell), so the same seed gives the same home at the same tick."""
        if state.armed or not (state.health.gps_fix_ok and state.health.local_position_ok):
            return False
        if self._home_try_ns is not None and state.t_ns - self._home_try_ns < 1_000_000_000:
            return False
        self._home_try_ns = state.t_ns
        return self.api.action.set_home(None).ok

    def _mission_refusals(self, now: int) -> None:
        for r in self.missions.pop_refusals():
            self._say(Severity.WARNING, r.reason, now)

    # ------------------------------------------------------------------ send
    def _say(self, severity: Severity, text: str, now: int) -> None:
        """STATUSTEXT to everyone; the same text is not repeated within 2 s (refusals and core events)."""
        if not text:
            return
        now = self._peer_now(now)  # a mission sees the same texts at any pace
        last = self._texts_sent.get(text)
        if last is not None and now - last < _TEXT_REPEAT_NS:
            return
        if len(self._texts_sent) > 256:
            self._texts_sent = {t: n for t, n in self._texts_sent.items() if now - n < _TEXT_REPEAT_NS}
        self._texts_sent[text] = now
        self._chunk_id += 1
        self._send_all([Out(msg) for msg in statustext(self.codec.mav, severity, text, self._chunk_id)], now)

    def _send_all(self, outs: list[Out], now: int) -> None:
        """Send what one instant produced: each destination gets its frames, in order, packed into as few
        datagrams as fit (``transport.pack_frames``), as ArduPilot's UDP ports do; one ``sendto`` per
        destination instead of one per frame."""
        if not outs:
            return
        if len(outs) == 1:
            self._send(outs[0], now)
            return
        dests: dict[bool, list[tuple[int, Address]]] = {}  # a batch at one instant: the same peers for all
        batches: dict[tuple[int, Address], list[bytes]] = {}
        for o in outs:
            data = self._encode(o)
            if o.to is not None:
                batches.setdefault((o.to.link, o.to.addr), []).append(data)
                continue
            targets = dests.get(o.wall_clock)
            if targets is None:
                targets = dests[o.wall_clock] = self._destinations(now, not o.wall_clock)
            for target in targets:
                batches.setdefault(target, []).append(data)
        sent = 0
        for (k, addr), frames in batches.items():
            link = self.links[k]
            for datagram, n in pack_frames(frames):
                sent += n if link.send(datagram, addr) else 0
        if sent:
            self._count("frames_tx", sent)

    def _send(self, out: Out, now: int) -> None:
        data = self._encode(out)
        if out.to is not None:
            sent = int(self.links[out.to.link].send(data, out.to.addr))
        else:
            sent = sum(self.links[k].send(data, addr) for k, addr in self._destinations(now, not out.wall_clock))
        if sent:
            self._count("frames_tx", sent)

    def _encode(self, out: Out) -> bytes:
        data = (self.codec if not out.compid else self._component_codecs[out.compid]).encode(out.msg)
        if self._tap is not None:
            self._tap(data)
        return data

    def _destinations(self, now: int, sim_peers: bool) -> list[tuple[int, Address]]:
        """(link index, address) pairs a message to everyone goes to now; without the peers on sim time when
        ``sim_peers`` is False (a wall-clock message)."""
        return [(k, addr) for k, link in enumerate(self.links) for addr in link.destinations(now, sim_peers=sim_peers)]
