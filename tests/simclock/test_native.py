"""simtime.c on a small C library of our own: its clock, sleeps, condition variables, futexes, polls and receives
follow the sim clock the test drives (hs_begin / hs_try_close), as MAVSDK's core does in a mission."""

from __future__ import annotations

import ctypes
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from harness.simclock import native, shim

pytestmark = pytest.mark.skipif(shim.compiler() is None, reason="no C compiler")

MS = 1_000_000
S = 1_000_000_000

LIB = r"""
#define _GNU_SOURCE
#include <poll.h>
#include <pthread.h>
#include <stdint.h>
#include <sys/socket.h>
#include <sys/syscall.h>
#include <linux/futex.h>
#include <time.h>
#include <unistd.h>
#include <errno.h>

static int64_t mono(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec * 1000000000LL + t.tv_nsec; }
int64_t lib_now(void) { return mono(); }
int64_t lib_wall(void) { struct timespec t; clock_gettime(CLOCK_REALTIME, &t); return t.tv_sec * 1000000000LL + t.tv_nsec; }

/* a thread of the library: sleeps `n` times `ms`, stamping the sim time after each */
static int64_t stamps[64]; static int nstamps, sleep_ms, sleeps;
static void *sleeper(void *p) { (void)p; for (int i = 0; i < sleeps; i++) { struct timespec d = {0, sleep_ms * 1000000L}; nanosleep(&d, 0); stamps[nstamps++] = mono(); } return 0; }
void start_sleeper(int ms, int n) { pthread_t t; sleep_ms = ms; sleeps = n; nstamps = 0; pthread_create(&t, 0, sleeper, 0); pthread_detach(t); }
int stamp_count(void) { return nstamps; }
int64_t stamp(int i) { return stamps[i]; }

/* a condition variable with a timed wait, signalled by the caller */
static pthread_mutex_t m = PTHREAD_MUTEX_INITIALIZER; static pthread_cond_t c; static int flag, waited_rc; static int64_t woke_at;
static void *cond_waiter(void *p) {
    int64_t timeout_ms = (int64_t)(intptr_t)p;
    pthread_mutex_lock(&m);
    struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t);
    int64_t dl = t.tv_sec * 1000000000LL + t.tv_nsec + timeout_ms * 1000000LL;
    t.tv_sec = dl / 1000000000LL; t.tv_nsec = dl % 1000000000LL;
    int rc = 0;
    while (!flag && rc == 0) rc = pthread_cond_timedwait(&c, &m, &t);
    waited_rc = rc; woke_at = mono();
    pthread_mutex_unlock(&m);
    return 0;
}
void start_cond_waiter(int timeout_ms) {
    pthread_condattr_t a; pthread_condattr_init(&a); pthread_condattr_setclock(&a, CLOCK_MONOTONIC);
    pthread_cond_init(&c, &a); flag = 0; waited_rc = -1;
    pthread_t t; pthread_create(&t, 0, cond_waiter, (void *)(intptr_t)timeout_ms); pthread_detach(t);
}
void signal_cond(void) { pthread_mutex_lock(&m); flag = 1; pthread_cond_signal(&c); pthread_mutex_unlock(&m); }
int cond_result(void) { return waited_rc; }
int64_t cond_woke_at(void) { return woke_at; }

/* a blocking receive on a UDP socket, then a futex wait that the caller wakes */
static int sock_fd; static int64_t recv_at; static int received;
static void *receiver(void *p) { (void)p; char b[64]; received = (int)recvfrom(sock_fd, b, sizeof b, 0, 0, 0); recv_at = mono(); return 0; }
void start_receiver(int fd) { sock_fd = fd; received = -2; pthread_t t; pthread_create(&t, 0, receiver, 0); pthread_detach(t); }
int receive_count(void) { return received; }
int64_t receive_at(void) { return recv_at; }

static uint32_t fut; static long fut_rc = -9;
static void *futex_waiter(void *p) { (void)p; fut_rc = syscall(SYS_futex, &fut, FUTEX_WAIT, 0, 0, 0, 0); return 0; }
void start_futex_waiter(void) { fut = 0; fut_rc = -9; pthread_t t; pthread_create(&t, 0, futex_waiter, 0); pthread_detach(t); }
void wake_futex(void) { __atomic_store_n(&fut, 1, __ATOMIC_SEQ_CST); syscall(SYS_futex, &fut, FUTEX_WAKE, 1, 0, 0, 0); }
long futex_result(void) { return fut_rc; }

/* poll with a timeout and no descriptors: a timed wait */
static int64_t polled_at;
static void *poller(void *p) { (void)p; poll(0, 0, 250); polled_at = mono(); return 0; }
void start_poller(void) { polled_at = -1; pthread_t t; pthread_create(&t, 0, poller, 0); pthread_detach(t); }
int64_t poll_done_at(void) { return polled_at; }

/* a futex wait of the caller's own thread (a Python thread calling into the library), ended by release_held */
static uint32_t held;
long wait_held(void) { return syscall(SYS_futex, &held, FUTEX_WAIT, 0, 0, 0, 0); }
void release_held(void) { __atomic_store_n(&held, 1, __ATOMIC_SEQ_CST); syscall(SYS_futex, &held, FUTEX_WAKE, 1, 0, 0, 0); }
"""


@pytest.fixture(scope="module")
def lib(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[ctypes.CDLL, native.NativeClock]]:
    d = tmp_path_factory.mktemp("simtime")
    src, so = d / "libsimtest.c", d / "libsimtest.so"
    src.write_text(LIB)
    cc = shim.compiler()
    assert cc is not None
    subprocess.run([*cc.split(), "-O1", "-shared", "-fPIC", "-o", str(so), str(src), "-lpthread"], check=True)
    test_lib = ctypes.CDLL(str(so))
    for name in ("lib_now", "lib_wall", "stamp", "cond_woke_at", "receive_at", "poll_done_at"):
        getattr(test_lib, name).restype = ctypes.c_int64
    test_lib.futex_result.restype = ctypes.c_long
    test_lib.wait_held.restype = ctypes.c_long
    clock = native.attach("libsimtest", epoch_ns=1_700_000_000 * S, now_ns=0)
    assert clock is not None and clock.patched >= 8
    yield test_lib, clock
    clock.close()


class Driver:
    """The clock thread's part: phases of ``period_ns``, each run until the library's threads are idle."""

    def __init__(self, clock: native.NativeClock, t_ns: int = 0, period_ns: int = 20 * MS) -> None:
        self.clock, self.t_ns, self.period_ns = clock, t_ns, period_ns

    def phase(self) -> None:
        self.clock.begin(self.t_ns)
        deadline = time.monotonic() + 10
        while not self.clock.try_close():
            g = self.clock.generation()
            self.clock.wait_change(g, 2 * MS)
            assert time.monotonic() < deadline, f"phase at {self.t_ns} never went idle: {self.clock.describe()}"
        self.t_ns += self.period_ns

    def until(self, t_ns: int) -> None:
        while self.t_ns <= t_ns:
            self.phase()


@pytest.fixture(scope="module")
def drive(lib: tuple[ctypes.CDLL, native.NativeClock]) -> Driver:
    """One sim clock for the module: its tests follow each other in sim time."""
    return Driver(lib[1])


def test_clock_reads_sim_time_and_the_run_epoch(lib: tuple[ctypes.CDLL, native.NativeClock], drive: Driver) -> None:
    test_lib, _ = lib
    drive.phase()
    t = drive.t_ns - drive.period_ns
    assert test_lib.lib_now() == t
    assert test_lib.lib_wall() == 1_700_000_000 * S + t


def test_sleeps_end_at_the_first_phase_at_or_after_their_deadline(
    lib: tuple[ctypes.CDLL, native.NativeClock], drive: Driver
) -> None:
    test_lib, _ = lib
    drive.clock.begin(drive.t_ns)  # the thread is created in a phase, as MAVSDK's are in a script's
    t0 = drive.t_ns
    test_lib.start_sleeper(30, 4)
    while not drive.clock.try_close():
        drive.clock.wait_change(drive.clock.generation(), MS)
    drive.t_ns += drive.period_ns
    drive.until(t0 + 200 * MS)
    assert test_lib.stamp_count() == 4
    stamps = [test_lib.stamp(i) - t0 for i in range(4)]
    # 30 ms sleeps on a 20 ms phase grid: each ends at the first phase at or after its deadline
    assert stamps == [40 * MS, 80 * MS, 120 * MS, 160 * MS], stamps


def test_a_timed_condition_wait_times_out_on_sim_time_and_a_signal_ends_it_at_once(
    lib: tuple[ctypes.CDLL, native.NativeClock], drive: Driver
) -> None:
    test_lib, clock = lib
    t0 = drive.t_ns
    clock.begin(t0)
    test_lib.start_cond_waiter(100)
    while not clock.try_close():
        clock.wait_change(clock.generation(), MS)
    drive.t_ns += drive.period_ns
    time.sleep(0.3)  # wall time passes: nothing happens
    assert test_lib.cond_result() == -1
    drive.until(t0 + 120 * MS)
    assert test_lib.cond_result() == 110  # ETIMEDOUT
    assert test_lib.cond_woke_at() - t0 == 100 * MS

    t1 = drive.t_ns
    clock.begin(t1)
    test_lib.start_cond_waiter(10_000)
    while not clock.try_close():
        clock.wait_change(clock.generation(), MS)
    clock.begin(t1)  # the same phase again: a signal from the script's side
    test_lib.signal_cond()
    while not clock.try_close():
        clock.wait_change(clock.generation(), MS)
    drive.t_ns += drive.period_ns
    assert test_lib.cond_result() == 0
    assert test_lib.cond_woke_at() == t1


def test_a_blocking_receive_waits_idle_and_data_between_phases_is_read_in_the_next_one(
    lib: tuple[ctypes.CDLL, native.NativeClock], drive: Driver
) -> None:
    test_lib, clock = lib
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        clock.begin(drive.t_ns)
        test_lib.start_receiver(rx.fileno())
        while not clock.try_close():
            clock.wait_change(clock.generation(), MS)
        drive.t_ns += drive.period_ns
        assert clock.snapshot().waits_for_io
        tx.sendto(b"hello", rx.getsockname())  # between phases: the thread must not run now
        time.sleep(0.2)
        assert test_lib.receive_count() == -2
        t = drive.t_ns
        drive.phase()
        assert test_lib.receive_count() == 5
        assert test_lib.receive_at() == t
    finally:
        rx.close()
        tx.close()


def test_a_futex_wait_is_idle_until_woken(lib: tuple[ctypes.CDLL, native.NativeClock], drive: Driver) -> None:
    test_lib, clock = lib
    clock.begin(drive.t_ns)
    test_lib.start_futex_waiter()
    while not clock.try_close():
        clock.wait_change(clock.generation(), MS)
    assert test_lib.futex_result() == -9  # still waiting, and the phase could end
    clock.begin(drive.t_ns)
    test_lib.wake_futex()
    while not clock.try_close():
        clock.wait_change(clock.generation(), MS)
    drive.t_ns += drive.period_ns
    assert test_lib.futex_result() == 0


def test_a_phase_does_not_end_on_a_look_taken_before_a_change(
    lib: tuple[ctypes.CDLL, native.NativeClock], drive: Driver
) -> None:
    """The runtime reads the generation, finds the script's threads idle, then asks to close: a change in between
    (a library thread released a script thread blocked in the library) keeps the phase open."""
    _, clock = lib
    clock.begin(drive.t_ns)
    seen = clock.generation()
    clock.poke()
    assert not clock.try_close(seen)
    assert clock.try_close(clock.generation())
    drive.t_ns += drive.period_ns


def test_poll_with_a_timeout_is_a_timed_wait(lib: tuple[ctypes.CDLL, native.NativeClock], drive: Driver) -> None:
    test_lib, clock = lib
    t0 = drive.t_ns
    clock.begin(t0)
    test_lib.start_poller()
    while not clock.try_close():
        clock.wait_change(clock.generation(), MS)
    drive.t_ns += drive.period_ns
    assert clock.snapshot().next_deadline_ns == t0 + 250 * MS
    drive.until(t0 + 260 * MS)
    assert test_lib.poll_done_at() - t0 == 260 * MS  # 250 ms on a 20 ms grid


def test_a_thread_waiting_in_the_shim_is_in_one_snapshot_of_its_state(
    lib: tuple[ctypes.CDLL, native.NativeClock], drive: Driver
) -> None:
    test_lib, clock = lib
    drive.phase()
    waiter = threading.Thread(target=test_lib.wait_held, name="blocked in the library")
    waiter.start()
    assert waiter.ident is not None
    deadline = time.monotonic() + 10
    while waiter.ident not in clock.snapshot().waiting:
        assert time.monotonic() < deadline, f"{waiter.ident} never waited: {clock.snapshot()}"
        time.sleep(0.001)
    state = clock.snapshot()  # between phases: nothing changes until the next one
    assert (state.generation, state.busy, state.sent, state.next_deadline_ns, state.waits_for_io) == (
        clock.generation(),
        clock.lib.hs_busy(),
        clock.sent(),
        clock.lib.hs_next_deadline(),
        bool(clock.lib.hs_waits_for_io()),
    )
    assert all(clock.lib.hs_thread_waiting(ident) for ident in state.waiting)
    assert threading.get_ident() not in state.waiting and clock.lib.hs_thread_waiting(waiter.ident)

    test_lib.release_held()  # between phases: it runs in the next one
    assert waiter.ident in clock.snapshot().waiting
    drive.phase()
    waiter.join(10)
    assert not waiter.is_alive()
    assert waiter.ident not in clock.snapshot().waiting


def test_a_shims_name_hashes_every_file_it_is_built_from(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    for path in shim.FOLDER.iterdir():
        if path.suffix in (".c", ".h"):
            shutil.copy(path, tmp_path / path.name)
    monkeypatch.setattr(shim, "FOLDER", tmp_path)
    names = {s.stem: shim.shim_name(s) for s in shim.SHIMS}
    assert {p.name for p in shim.MISSION.files()} >= {"simtime.c", "simtime.h", "simcommon.h", "simtime_patch.c"}
    assert {p.name for p in shim.CHILD.files()} == {"simchild.c", "simcommon.h"}

    with (tmp_path / "simcommon.h").open("a") as f:
        f.write("/* shared by both */\n")
    edited = {s.stem: shim.shim_name(s) for s in shim.SHIMS}
    assert all(edited[stem] != names[stem] for stem in names), "a shared header renames both shims"

    with (tmp_path / "simtime_io.c").open("a") as f:
        f.write("/* the mission's only */\n")
    assert shim.shim_name(shim.MISSION) != edited["simtime"]
    assert shim.shim_name(shim.CHILD) == edited["simchild"]


def test_without_a_compiler_the_library_keeps_the_wall_clock(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))  # nothing built yet there
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setattr(shim, "_warned", False)
    monkeypatch.setattr(shim, "packaged_path", lambda source: tmp_path / "not-built.so")  # a package built without
    assert shutil.which("cc") is None
    assert shim.build() is None
    assert shim.build() is None
    warnings = [r.message for r in caplog.records if "no C compiler" in r.message]
    assert warnings == [
        "no C compiler (cc, gcc or clang): MAVSDK's own threads and the mission's C-level waits stay on the wall clock"
    ]


def test_many_processes_build_it_once_into_an_empty_cache(tmp_path: Path) -> None:
    code = "from harness.simclock import shim; print(shim.cached())"
    env = {"XDG_CACHE_HOME": str(tmp_path)}
    procs = [
        subprocess.Popen([sys.executable, "-c", code], env={**os.environ, **env}, stdout=subprocess.PIPE, text=True)
        for _ in range(4)
    ]
    outs = {p.communicate(timeout=120)[0].strip() for p in procs}
    assert all(p.returncode == 0 for p in procs)
    assert len(outs) == 1
    built = [p for p in (tmp_path / "uav-harness").iterdir() if p.suffix == ".so"]
    assert [p.name for p in built] == [Path(outs.pop()).name]
