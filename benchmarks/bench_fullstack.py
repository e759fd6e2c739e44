"""Full-stack benchmark: real-time factor of `harness run` with physics, autopilots, the built-in network
and one MAVSDK mission process per vehicle (`missions/hover.py`: take off, hover 30 s, land, broadcasting
its position over the radio at 10 Hz and reading what every other vehicle sends), at the shipped default
rates (physics 1 kHz, control tick 250 Hz, phases 0/1 every 5th tick = 50 Hz, i.e. a 20 ms phase-0 period).

    .venv/bin/python benchmarks/bench_fullstack.py                 # 1, 10 and 50 vehicles
    .venv/bin/python benchmarks/bench_fullstack.py 1 10 --repeat 3 # chosen sizes, median of 3 runs
    .venv/bin/python benchmarks/bench_fullstack.py 1 --firmware ardupilot  # ArduCopter vehicles, DroneKit missions
    .venv/bin/python benchmarks/bench_fullstack.py 1 10 --firmware px4,ardupilot-mavsdk  # both personalities, same client
    .venv/bin/python benchmarks/bench_fullstack.py 10 --workers 1,2       # vehicles in 1 and 2 processes, interleaved

With ``--firmware ardupilot`` the vehicles present the ArduCopter personality and each mission is
``missions/hover_dronekit.py`` (the same flight and beacons with DroneKit over SERIAL0, TCP) instead.

Figures per size:
- RTF: sim time / wall time of the whole run, as ``summary.json`` reports it (start-up included); with
  ``--repeat`` the median over the runs (of an even count, the mean of the middle two);
- flight RTF: the same from the first vehicle leaving the ground to the last one landing (from the tick
  timing in ``world.mcap``): the rate while everything flies, without MAVSDK's start-up on the ground;
- CPU seconds per process class (read from /proc while the run goes, of the median run): ``harness run``
  itself (the root, with its own share of vehicles), the autopilot hosts (``--workers``), the mission
  processes (and the fork server they are forked from), their ``mavsdk_server`` processes, the network process.

Targets (issue 7, 2-core machine): >= 30x for 1 vehicle, >= 3x for 10, >= 0.5x for 50.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path

from bare_jsbsim import bare_rtf  # a sibling script: run as a script, this one's folder is on sys.path

ROOT = Path(__file__).resolve().parents[1]

TARGETS = {1: 30.0, 10: 3.0, 50: 0.5}
BEACON_HZ = 10.0
CLK_TCK = os.sysconf("SC_CLK_TCK")


def _cpu_of(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def _kind(pid: int, root: int) -> str:
    if pid == root:
        return "harness run"
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            cmd = f.read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""
    if "mavsdk_server" in cmd:
        return "mavsdk_server"
    if " mission " in cmd or "harness.run.forkserver" in cmd:  # missions are forked from the run's fork server
        return "missions"
    if "harness.autopilot.sitl" in cmd:
        return "hosts"
    if "net.subscriber" in cmd:
        return "network"
    return "other" if cmd else ""


class CpuMeter:
    """Samples the CPU time of a process tree every 0.2 s (the last reading of each process counts)."""

    def __init__(self, root: int) -> None:
        self.root = root
        self.seen: dict[int, tuple[str, float]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _children(self, pid: int) -> list[int]:
        try:
            with open(f"/proc/{pid}/task/{pid}/children") as f:
                return [int(x) for x in f.read().split()]
        except OSError:
            return []

    def _run(self) -> None:
        while not self._stop.is_set():
            todo = [self.root]
            while todo:
                pid = todo.pop()
                todo += self._children(pid)
                try:
                    cpu = _cpu_of(pid)
                except (OSError, IndexError, ValueError):
                    continue
                kind = _kind(pid, self.root) or self.seen.get(pid, ("other", 0.0))[0]
                self.seen[pid] = (kind, cpu)
            self._stop.wait(0.2)

    def stop(self) -> dict[str, float]:
        self._stop.set()
        self._thread.join()
        out: dict[str, float] = {}
        for kind, cpu in self.seen.values():
            out[kind] = out.get(kind, 0.0) + cpu
        return out


def flight_rtf(out: Path) -> float:
    """Sim time / wall time from the first vehicle off the ground to the last one back on it."""
    from harness.record.world import read_topics

    topics = read_topics(out / "world.mcap")
    airborne = [
        s["t_s"] for name, msgs in topics.items() if name.endswith("/state") for s in msgs if not s["on_ground"]
    ]
    if not airborne:
        return 0.0
    t0, t1 = min(airborne), max(airborne)
    ticks = [(m["t_s"], m["wall_s"]) for m in topics.get("/sim/tick", []) if t0 <= m["t_s"] <= t1]
    if len(ticks) < 2 or ticks[-1][1] <= ticks[0][1]:
        return 0.0
    return (ticks[-1][0] - ticks[0][0]) / (ticks[-1][1] - ticks[0][1])


@dataclass
class Result:
    sim_s: float
    wall_s: float
    rtf: float
    flight_rtf: float
    ok: bool
    cpu: dict[str, float]
    out: Path


STACKS = {
    "px4": ("px4", "hover.py"),
    "ardupilot": ("ardupilot", "hover_dronekit.py"),
    "ardupilot-mavsdk": ("ardupilot", "hover.py"),
    "native": ("px4", "takeoff_and_land_native.py"),
}
"""By --firmware: the vehicles' personality and each vehicle's mission. "ardupilot-mavsdk" is the ArduCopter
personality flown by the PX4 benchmark's own MAVSDK mission (MAVSDK speaks both dialects), so the two
personalities are compared with the same client; "native" is a PX4 vehicle with a native-API (mavsdk >= 4)
mission that takes off, hovers and lands, without radio beacons (issue 13's acceptance flight)."""
CLIENTS = {
    "px4": "MAVSDK (gRPC API)",
    "ardupilot": "DroneKit",
    "ardupilot-mavsdk": "MAVSDK (gRPC API)",
    "native": "MAVSDK (native API, no beacons)",
}
VIEWS = ("off", "file", "web")
"""The 3D view: off (``HARNESS_RRD=0``: world.mcap only), file (world.rrd, the default when Rerun is
installed), web (``--view web``: world.rrd and the live stream served, with no viewer connected)."""


def run(
    vehicles: int, hover_s: float, view: str = "file", speed: str = "max", firmware: str = "px4", workers: str = "auto"
) -> Result:
    out = Path(tempfile.mkdtemp(prefix=f"bench-fullstack-{vehicles}-"))
    cmd = [
        sys.executable,
        "-m",
        "harness.cli",
        "run",
        "--vehicles",
        str(vehicles),
        "--network",
        "builtin",
        "--firmware",
        STACKS[firmware][0],
        "--mission",
        str(ROOT / "missions" / STACKS[firmware][1]),
        "--out",
        str(out),
        *(["--view", "web"] if view == "web" else []),
        "--speed",
        speed,
        "--workers",
        workers,
        "--",
        str(hover_s),
        *([] if firmware == "native" else [str(BEACON_HZ)]),
    ]
    env = dict(os.environ, HARNESS_RRD="0" if view == "off" else "1", XDG_CONFIG_HOME=str(out / "xdg"))
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    meter = CpuMeter(proc.pid)
    _, err = proc.communicate(timeout=3600)
    cpu = meter.stop()
    summary = json.loads((out / "summary.json").read_text())
    if proc.returncode != 0:
        print(f"  run of {vehicles} failed ({summary.get('message')}); see {out}\n{err[-2000:]}", file=sys.stderr)
    return Result(
        summary["sim_time_s"],
        summary["wall_time_s"],
        summary["real_time_factor"],
        flight_rtf(out),
        proc.returncode == 0,
        cpu,
        out,
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sizes", nargs="*", type=int, default=[1, 10, 50])
    ap.add_argument("--repeat", type=int, default=1, help="runs per size; the median RTF is reported")
    ap.add_argument("--hover", type=float, default=30.0, help="seconds of hover in the mission")
    ap.add_argument(
        "--firmware",
        default="px4",
        help=f"comma-separated personalities and mission clients to compare, runs interleaved: {', '.join(STACKS)} "
        "(e.g. px4,ardupilot-mavsdk: both personalities with the same MAVSDK mission)",
    )
    ap.add_argument(
        "--views",
        default="file",
        help="comma-separated 3D-view settings to compare, runs interleaved: off (no world.rrd), file (world.rrd, "
        "the default), web (--view web, no viewer connected); e.g. --views off,web",
    )
    ap.add_argument(
        "--speed",
        default="max",
        help="pace the runs (e.g. 1): CPU per process class then shows each setting's work without the "
        "contention of a run as fast as possible",
    )
    ap.add_argument(
        "--workers",
        default="auto",
        help="comma-separated `harness run --workers` settings to compare, runs interleaved (e.g. 1,2; "
        "default auto, as harness run)",
    )
    a = ap.parse_args()
    views = a.views.split(",")
    workers = a.workers.split(",")
    if any(w != "auto" and not w.isdigit() for w in workers):
        ap.error(f"--workers: numbers or auto, got {a.workers!r}")
    stacks = a.firmware.split(",")
    settings = [(v, w, f) for v in views for w in workers for f in stacks]
    if any(v not in VIEWS for v in views):
        ap.error(f"--views: each of {VIEWS}, got {a.views!r}")
    if any(f not in STACKS for f in stacks):
        ap.error(f"--firmware: each of {', '.join(STACKS)}, got {a.firmware!r}")
    for f in stacks:
        print(
            f"full stack ({f}): JSBSim physics + {STACKS[f][0]} autopilots + MAVLink + built-in network + "
            f"1 {CLIENTS[f]} mission per vehicle"
        )
    print(
        f"rates: physics 1000 Hz, tick 250 Hz, phase 0/1 every 5th tick (20 ms); mission: takeoff, hover "
        f"{a.hover:g} s, land"
        + ("" if stacks == ["native"] else f"; {BEACON_HZ:g} Hz radio beacons to every vehicle (not native)")
    )
    print(
        f"{'view':>5} {'wk':>4} {'vehicles':>8} {'sim s':>7} {'wall s':>7} {'RTF':>7} {'flight':>7} {'target':>7} {'ok':>3} "
        f"{'bare':>7} {'eff.':>5}   CPU s: harness run / hosts / missions / mavsdk_server / network"
    )
    for n in a.sizes:
        by_setting: dict[tuple[str, str, str], list[Result]] = {s: [] for s in settings}
        for _ in range(a.repeat):  # interleaved, so a change in the machine's load hits every setting alike
            for v, w, f in settings:
                by_setting[v, w, f].append(run(n, a.hover, v, a.speed, f, w))
        bare = bare_rtf(n)
        for (v, w, f), runs in by_setting.items():
            label = f"{v:>5} {w:>4}" + (f" {f}" if len(stacks) > 1 else "")
            report(label, n, sorted(runs, key=lambda x: x.rtf), a.repeat, bare)
    return 0


def report(setting: str, n: int, runs: list[Result], repeat: int, bare: float) -> None:
    """One line: the median run, and its efficiency = its RTF / the RTF of ``n`` bare JSBSim instances
    (``bare_jsbsim.py``), measured in the same session (machines here differ ~2.5x in speed; the ratio less)."""
    r = runs[len(runs) // 2]
    rtf = statistics.median(x.rtf for x in runs)  # of an even count: the mean of the middle two
    flight = statistics.median(x.flight_rtf for x in runs)
    spread = "  (runs: " + ", ".join(f"{x.rtf:.2f}" for x in runs) + ")" if repeat > 1 else ""
    cpu = r.cpu
    print(
        f"{setting} {n:>8} {r.sim_s:>7.1f} {r.wall_s:>7.1f} {rtf:>6.2f}x {flight:>6.2f}x "
        f"{TARGETS.get(n, 0.0):>6.1f}x {int(all(x.ok for x in runs)):>3} {bare:>6.2f}x {rtf / bare:>5.3f}   "
        f"{cpu.get('harness run', 0):.1f} / {cpu.get('hosts', 0):.1f} / {cpu.get('missions', 0):.1f} / "
        f"{cpu.get('mavsdk_server', 0):.1f} / {cpu.get('network', 0):.1f}{spread}",
        flush=True,
    )


if __name__ == "__main__":
    sys.exit(main())
