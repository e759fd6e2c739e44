"""Benchmark of the lockstep core: wall time per tick over real sockets, versus vehicles and subscribers.

Every participant is its own process: the channel (``harness channel``), one fake autopilot host for all
vehicles, the type-0 and type-1 subscribers, and the fake physics (this process). Phases run on every
tick (phase_every=1, the worst case). Run:

    .venv/bin/python benchmarks/bench_channel.py            # full table
    .venv/bin/python benchmarks/bench_channel.py --quick    # fewer ticks
    .venv/bin/python benchmarks/bench_channel.py --case local,100,100,1 --case tcp,10,10,1  # chosen cases

Besides the wall time per tick, "chan CPU us" is the CPU time the channel's process spends per tick: the
``harness channel`` process (from /proc, 10 ms resolution), or, for ``local``, this process — the root channel
inside physics, as in ``harness run``, with the fake physics' own small share. CPU time hardly moves with the
machine's load, where the wall time does.

Target (issue 2): <= 100 us per tick for 1 vehicle + 1 type-0 + 1 type-1 on a 2-core machine, and cost
growing no worse than linearly with vehicles and subscribers.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from harness.channel import Channel, ChannelConfig
from harness.channel.drivers import run_fake_physics, run_fake_physics_local


@dataclass
class Result:
    transport: str
    vehicles: int
    type0: int
    type1: int
    median_us: float
    mean_us: float
    p99_us: float
    cpu_us: float
    """CPU time of the channel's process per tick."""


def _cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _wait_ready(files: list[Path], procs: list[subprocess.Popen[bytes]]) -> None:
    deadline = time.monotonic() + 60
    while not all(f.exists() for f in files):
        if any(p.poll() is not None for p in procs):
            raise RuntimeError("a subscriber process died before subscribing")
        if time.monotonic() > deadline:
            raise RuntimeError("subscribers did not subscribe within 60 s")
        time.sleep(0.02)


def run_case(transport: str, vehicles: int, type0: int, type1: int, ticks: int) -> Result:
    """``transport``: tcp/unix = channel in its own process; local = root channel inside physics."""
    py = sys.executable
    listen = f"unix:///tmp/harness-bench-{time.monotonic_ns()}.sock" if transport == "unix" else "tcp://127.0.0.1:0"
    local: Channel | None = None
    procs: list[subprocess.Popen[bytes]] = []
    if transport == "local":
        local = Channel(ChannelConfig(address=listen, phase_every=1, stall_timeout_s=30))
        local.attach_physics()
        address = local.address
        chan = subprocess.Popen([py, "-c", "pass"])
    else:
        chan = subprocess.Popen(
            [py, "-m", "harness.cli", "channel", "--listen", listen, "--phase-every", "1", "--stall-timeout", "30"],
            stdout=subprocess.PIPE,
        )
        assert chan.stdout is not None
        address = chan.stdout.readline().decode().strip().rsplit(" ", 1)[-1]
    try:
        tmp = Path(tempfile.mkdtemp(prefix="harness-bench-"))
        ready: list[Path] = []

        def start(*args: str) -> None:
            ready.append(tmp / f"ready-{len(ready)}")
            drv = [py, "-m", "harness.channel.drivers", *args, "--address", address, "--ready", str(ready[-1])]
            procs.append(subprocess.Popen(drv))

        start("autopilot", *[a for v in range(vehicles) for a in ("--vehicle", str(v))])
        for i in range(type0):
            start("type0", "--vehicle", str(i % vehicles))
        for _ in range(type1):
            start("type1")
        if local is not None:
            if not local.wait_for(lambda subs: len(subs) == len(procs), 60):
                raise RuntimeError("subscribers did not subscribe within 60 s")
            cpu0 = time.process_time()
            stats = run_fake_physics_local(local, vehicles, ticks)
            cpu_s = time.process_time() - cpu0
            local.close()
        else:
            _wait_ready(ready, procs)
            cpu0 = _cpu_s(chan.pid)
            stats = run_fake_physics(address, vehicles, ticks, trace=False)
            cpu_s = _cpu_s(chan.pid) - cpu0
        for p in procs:
            p.wait(20)
        samples = sorted(stats.tick_wall_ns[ticks // 10 :])  # skip warm-up
        return Result(
            transport,
            vehicles,
            type0,
            type1,
            statistics.median(samples) / 1e3,
            statistics.fmean(samples) / 1e3,
            samples[int(len(samples) * 0.99)] / 1e3,
            cpu_s / ticks * 1e6,
        )
    finally:
        for p in [*procs, chan]:
            if p.poll() is None:
                p.kill()
            p.wait()


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument(
        "--case",
        action="append",
        default=[],
        metavar="TRANSPORT,VEHICLES,TYPE0,TYPE1",
        help="run only these cases (repeatable), e.g. local,100,100,1",
    )
    a = ap.parse_args()
    ticks = 1000 if a.quick else 3000
    chosen = []
    for text in a.case:
        parts = text.split(",")
        if len(parts) != 4 or parts[0] not in ("tcp", "unix", "local") or not all(x.isdigit() for x in parts[1:]):
            ap.error(f"--case: expected TRANSPORT,VEHICLES,TYPE0,TYPE1 with tcp, unix or local, got {text!r}")
        chosen.append((parts[0], int(parts[1]), int(parts[2]), int(parts[3])))
    cases = chosen or [
        ("tcp", 1, 1, 1),
        ("unix", 1, 1, 1),
        ("local", 1, 1, 1),
        ("local", 10, 1, 1),
        ("local", 100, 1, 1),
        ("tcp", 10, 1, 1),
        ("tcp", 100, 1, 1),
        ("unix", 100, 1, 1),
        ("tcp", 1, 4, 1),
        ("tcp", 1, 16, 1),
        ("tcp", 1, 1, 4),
        ("tcp", 10, 10, 1),
    ]
    print(f"lockstep core, {ticks} ticks per case, phases on every tick, every participant its own process")
    print(
        f"{'transport':>9} {'vehicles':>8} {'type0':>5} {'type1':>5} {'median us':>10} {'mean us':>9} {'p99 us':>8} "
        f"{'chan CPU us':>11}"
    )
    results = []
    for case in cases:
        r = run_case(*case, ticks=ticks)
        results.append(r)
        print(
            f"{r.transport:>9} {r.vehicles:>8} {r.type0:>5} {r.type1:>5} {r.median_us:>10.1f} {r.mean_us:>9.1f} "
            f"{r.p99_us:>8.1f} {r.cpu_us:>11.1f}",
            flush=True,
        )
    if chosen:
        return 0
    base = results[0].median_us
    print(
        f"\ntarget: <= 100 us/tick for 1 vehicle + 1 type-0 + 1 type-1 -> measured {base:.1f} us "
        f"(ratio {100.0 / base:.2f}x of target)"
    )
    v100 = next(r for r in results if r.vehicles == 100 and r.transport == "tcp")
    print(
        f"scaling 1 -> 100 vehicles: x{v100.median_us / base:.1f} cost for x100 vehicles "
        f"({(v100.median_us - base) / 99:.1f} us per extra vehicle)"
    )
    s16 = next(r for r in results if r.type0 == 16)
    print(
        f"scaling 1 -> 16 type-0: x{s16.median_us / base:.1f} ({(s16.median_us - base) / 15:.1f} us per extra subscriber)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
