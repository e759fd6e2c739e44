"""``harness mission SCRIPT``: run an unmodified script as a type-0 subscriber on the sim clock.

The process connects to the channel, patches time (``patch.install``), starts the *clock thread* that
answers BEGIN-TICK-0 with END-TICK-0 once the script is idle, and runs SCRIPT as ``__main__`` in the
main thread. When the script ends — returns, raises, calls ``sys.exit`` — the runner reports the exit
code to the channel (BYE) and ends the process itself, even if a library left a non-daemon thread
behind (``mavsdk-grpc`` does). When the run ends first, the script is stopped with exit code
:data:`EXIT_RUN_ENDED`. Saying so and ending the process are the caller's (:class:`MissionHooks`, given by
``harness mission`` in ``cli.py``); this module neither prints nor exits.
"""

from __future__ import annotations

import _thread
import logging
import os
import runpy
import sys
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

from harness.core.clock import NS_PER_S
from harness.core.endpoints import VehicleEndpoints, sysid
from harness.core.errors import ScenarioError
from harness.simclock import iowait, mavsdk_compat, native, patch, simsocket
from harness.simclock.mailbox import Delivery
from harness.simclock.runtime import SimRuntime
from harness.simclock.threads import HarnessThread
from harness.wire import protocol as p
from harness.wire.client import ChannelClient, ChannelClosed

log = logging.getLogger(__name__)

EXIT_RUN_ENDED = 124
"""Exit code of a mission whose simulation ended (or dropped it) before the script finished."""


@dataclass(frozen=True)
class MissionSpec:
    script: Path
    args: tuple[str, ...]
    channel: str
    vehicle: int
    name: str


@dataclass(frozen=True)
class MissionHooks:
    """What the mission runner needs of its process (``harness mission`` gives them)."""

    report: Callable[[str], None]
    """Tell the user one line (the mission's stderr)."""
    end_process: Callable[[int], NoReturn]
    """End the process with this exit code now, whatever threads the script left (see :func:`kill_descendants`)."""


BYE_WAIT_S = 30.0
"""How long (wall clock) the main thread waits for the clock thread to end the script's last phase with BYE
before it says BYE itself (the run is over or its channel gone)."""


def _release(lock: _thread.LockType) -> None:
    if lock.locked():
        lock.release()


class _ClockThread(HarnessThread):
    def __init__(self, client: ChannelClient, rt: SimRuntime, hooks: MissionHooks) -> None:
        super().__init__(name="harness-clock", daemon=True)
        self.client = client
        self.rt = rt
        self.hooks = hooks
        self.end_reason: str | None = None
        self.seq = 0
        self.script_done = False
        self.exit_code: int | None = None
        """Set by the main thread when the script has ended: the phase it ended in answers with BYE."""
        self.said_bye = _thread.allocate_lock()
        """Released once the clock thread has said BYE (a raw lock: ``threading`` waits are sim-time waits, and
        no phase comes after the last one to release them)."""
        self.said_bye.acquire()

    def run(self) -> None:
        if self.rt.native is not None:
            self.rt.native.set_wall()  # the clock thread's own waits are on the wall clock, in every library
        try:
            while True:
                for msg in self.client.recv():
                    if isinstance(msg, p.BeginTick0):
                        idle_until, deliver_wakes, mavlink_wakes = self.rt.run_phase(msg.t_ns)
                        out: list[p.Message] = []
                        for o in self.rt.take_outbox():
                            pk = p.Packet(msg.t_ns, self.rt.vehicle, o.dst, o.port, self.seq, o.payload)
                            self.seq += 1
                            out.append(p.Enqueue(pk))
                        code = self.exit_code
                        if code is None:
                            out.append(p.EndTick0(msg.t_ns, idle_until, deliver_wakes, mavlink_wakes))
                        self.client.send_many(out)
                        if code is not None:  # the phase the script ended in: its answer is BYE, at any pace
                            self.client.close(f"script exited with {code}", code)
                            _release(self.said_bye)
                            return
                    elif isinstance(msg, p.Deliver):
                        self.rt.deliver([_delivery(msg)])
                    elif isinstance(msg, p.DeliverMany):
                        self.rt.deliver([_delivery(d) for d in msg.delivers])
                    elif isinstance(msg, p.Bye):
                        self._end(f"the simulation ended ({msg.reason or 'no reason given'})")
                        return
                    elif isinstance(msg, p.Error):
                        self._end(f"the channel dropped this mission: {msg.message}")
                        return
        except ChannelClosed as exc:
            self._end(str(exc))
        except Exception as exc:  # a bug in the clock must not leave the script hanging
            log.exception("clock thread failed")
            self._end(f"internal error in the sim clock: {exc!r}")

    def _end(self, reason: str) -> None:
        if self.script_done:
            _release(self.said_bye)  # the script ended first; the main thread says BYE (if it can) and exits
            return
        self.end_reason = reason
        self.rt.close()
        self.hooks.report(f"{reason}; stopping the script")
        # Give the script a moment to finish on its own (its waits were all released), then end it.
        self.rt.wall.sleep_ns(2 * NS_PER_S)
        self.hooks.end_process(EXIT_RUN_ENDED)


class _WakeThread(HarnessThread):
    """Asks the channel for a phase when a C-level wait of the process became ready between phases (the shim's
    ``want_fd``): what wakes a Python thread's wait does so itself (``SimRuntime.want_phase``)."""

    def __init__(self, rt: SimRuntime, fd: int) -> None:
        super().__init__(name="harness-wake", daemon=True)
        self.rt = rt
        self.fd = fd

    def run(self) -> None:
        if self.rt.native is not None:
            self.rt.native.set_wall()
        while not self.rt.closed:
            iowait.real_select([self.fd], [], [], None)
            try:
                os.read(self.fd, 8)
            except BlockingIOError:
                continue
            self.rt.want_phase()


def _forget_python() -> None:
    """In a process forked from the mission without exec: no Python-level sim clock (there is no clock thread);
    its time and waits are C calls, on ``simchild.c``'s side of the mission's lockstep."""
    simsocket.uninstall()
    patch.uninstall()


def _delivery(msg: p.Deliver) -> Delivery:
    pk = msg.packet
    return Delivery(msg.at_ns, pk.src, pk.dst, pk.port, pk.payload, msg.rssi_dbm)


def _children(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            return [int(x) for x in f.read().split()]
    except OSError:
        return []


def kill_descendants() -> None:
    """Stop whatever the script started (mavsdk_server for the gRPC API): no orphans."""
    import signal

    todo, seen = _children(os.getpid()), []
    while todo:
        pid = todo.pop()
        seen.append(pid)
        todo += _children(pid)
    for pid in seen:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass


def run_script(script: Path, args: Sequence[str]) -> int:
    """Run ``script`` as ``__main__``; return its exit code (tracebacks go to stderr)."""
    sys.argv = [str(script), *args]
    sys.path.insert(0, str(script.parent.resolve()))
    try:
        runpy.run_path(str(script), run_name="__main__")
    except SystemExit as exc:
        code = exc.code
        if code is None:
            return 0
        if isinstance(code, int):
            return code
        sys.stderr.write(f"{code}\n")
        return 1
    except KeyboardInterrupt:
        return 130
    except BaseException:
        traceback.print_exc()
        return 1
    return 0


def run_mission(spec: MissionSpec, hooks: MissionHooks) -> int:
    """Connect, patch, run the script on the sim clock, report, and return the exit code."""
    if not spec.script.is_file():
        raise ScenarioError(f"mission script {spec.script} does not exist")
    native.build_all()  # before it subscribes: a compile on a loaded machine must not count against the watchdog
    client = ChannelClient.connect(spec.channel, p.PeerKind.TYPE0, spec.name, vehicle=spec.vehicle)
    rt = SimRuntime(client.welcome.epoch_ns, client.welcome.phase_period_ns, spec.vehicle)
    os.environ.setdefault("HARNESS_VEHICLE", str(spec.vehicle))
    os.environ.setdefault("HARNESS_SYSID", str(sysid(spec.vehicle)))
    patch.install(rt)
    ep = VehicleEndpoints.from_env(spec.vehicle)
    from harness.simclock import udp

    udp.install(rt, ep)  # sockets: sim-time waits, MAVLink to this vehicle, UDP to 10.42.0.x on the radio
    # C-level waits and clocks of the interpreter and of every C extension (docs/simclock.md)
    rt.native = native.attach_process(rt.epoch_ns, rt.now_ns(), _forget_python)
    forced = os.environ.get("HARNESS_MAVSDK_API") or None
    if forced is not None and forced not in set(mavsdk_compat.MavsdkApi):
        choices = ", ".join(a.value for a in mavsdk_compat.MavsdkApi if a.value)
        raise ScenarioError(f"HARNESS_MAVSDK_API={forced!r}: expected one of {choices}")
    api = mavsdk_compat.install(spec.script, ep, mavsdk_compat.MavsdkApi(forced) if forced else None)
    if api:
        log.info("mission %s: MAVSDK %s API, vehicle endpoints %s", spec.name, api, ep)

    def wake() -> None:
        try:
            client.send(p.Wake())
        except ChannelClosed:
            pass  # the run is over; the clock thread ends the script

    rt.request_phase = wake
    trace_dir = os.environ.get("HARNESS_SIMTIME_TRACE_DIR")
    if trace_dir:  # every end of phase 0 and why each thread counted idle, beside MAVSDK's (docs/simclock.md)
        rt.trace = open(os.path.join(trace_dir, f"simclock-{spec.vehicle}.trace"), "w")  # noqa: SIM115
    if rt.native is not None:  # before the clock thread: no phase has begun, so Thread.start's wait is a real one
        _WakeThread(rt, rt.native.want_fd()).start()
    clock = _ClockThread(client, rt, hooks)
    clock.start()
    rt.wait_first_phase()
    if rt.trace is not None:
        rt.trace.write(f"{rt.now_ns()} script starts\n")
    code = run_script(spec.script, spec.args)
    if code == 0:
        for t in rt.threads.live_own_threads():  # a normal end waits for the script's own threads, as Python does,
            while t.is_alive():  # looking at a phase (a sim-time wait), not whenever the OS ran this thread
                time.sleep(rt.phase_period_ns / NS_PER_S)
    if rt.native is not None:
        rt.native.set_wall()  # what the main thread waits for from now on is the clock thread's BYE, on the wall clock
    clock.script_done = True
    clock.exit_code = code
    rt.threads.thread_done()  # the phase ends once the library threads are idle too, and answers BYE (the clock thread)
    rt.want_phase()  # should this be between phases after all: the channel calls the mission once more
    if not clock.said_bye.acquire(True, BYE_WAIT_S):
        try:
            client.close(f"script exited with {code}", code)
        except Exception:
            pass
    return code
