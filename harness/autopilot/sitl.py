"""The autopilot process of a run (SITL-like): autopilots in lockstep, each with its MAVLink server and tlog.

Parameters a ground station sets are kept in ``<run dir>/params/vehicle-<i>.json`` and restored when the
vehicle starts again in the same run directory.

With ``LaunchPlan(autopilots=AutopilotPlacement.PROCESS)``, ``harness run`` starts one of these for all vehicles (one
process for several vehicles is cheaper than one per vehicle, ``docs/autopilot.md``); with ``--workers N``, one per
share after the first. Given ``--physics FILE`` (the run's ``physics.json``) it steps its vehicles' physics too and
sends their ground truth up with each END-TICK-AC (``docs/tree.md``, "Every core"). Each vehicle gets a
MAVLink server on API port ``api_port_base + i`` and the GCS port (one ``MavlinkHub`` thread serves them
all) and writes ``vehicle-<i>.tlog`` in the run directory: every MAVLink frame it sent or received, each preceded by its 8-byte big-endian Unix time in
microseconds (the format of QGroundControl and MAVProxy telemetry logs).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import logging
import struct
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import BinaryIO

from harness.autopilot.autopilot import Autopilot, AutopilotConfig
from harness.autopilot.firmware import Firmware, firmware_of
from harness.autopilot.flightlog import FlightLog
from harness.autopilot.host import make_autopilots, run_autopilots
from harness.autopilot.mavlink.codec import SigningConfig
from harness.autopilot.mavlink.hub import MavlinkHub
from harness.autopilot.mavlink.param_store import persist_params
from harness.autopilot.mavlink.personality import core_param_defaults
from harness.autopilot.mavlink.runlocal import RunLocalPeers
from harness.autopilot.mavlink.server import MavlinkServer
from harness.autopilot.mavlink.transport import PortsConfig
from harness.autopilot.process_config import AutopilotProcessConfig
from harness.core import lifeline
from harness.core.clock import WALL, Clock
from harness.core.errors import HarnessError, ScenarioError
from harness.core.secrets import read_signing_key
from harness.fdm.physics import Physics, PhysicsConfig

log = logging.getLogger(__name__)

_STAMP = struct.Struct(">Q")


class TlogWriter:
    """Appends MAVLink frames to a ``.tlog``; flushed every ``flush_every`` frames and on close. A write that
    fails (a full disk) closes it and is kept in :attr:`error`: the MAVLink side goes on, the run reports it."""

    def __init__(self, path: Path, flush_every: int = 50, clock: Clock = WALL) -> None:
        self.path = path
        self._f: BinaryIO = path.open("ab")
        self._clock = clock
        self._n = 0
        self._flush_every = flush_every
        self._lock = threading.Lock()
        self.closed = False
        self.error: OSError | None = None

    def write(self, frame: bytes) -> None:
        with self._lock:
            if self.closed:
                return
            try:
                self._f.write(_STAMP.pack(self._clock.unix_ns() // 1000) + frame)
                self._n += 1
                if self._n % self._flush_every == 0:
                    self._f.flush()
            except OSError as exc:
                self._failed(exc)

    def _failed(self, exc: OSError) -> None:
        self.error, self.closed = exc, True
        with contextlib.suppress(OSError):
            self._f.close()  # flushes once more, and fails again: closed all the same

    def close(self) -> None:
        with self._lock:
            if not self.closed:
                self.closed = True
                try:
                    self._f.close()
                except OSError as exc:
                    self._failed(exc)


class AttachedMavlink:
    def __init__(self, server: MavlinkServer, tlog: TlogWriter | None, ulog: FlightLog | None = None) -> None:
        self.server = server
        self.tlog = tlog
        self.ulog = ulog

    def close(self) -> None:
        self.server.stop()
        if self.tlog is not None:
            self.tlog.close()
        if self.ulog is not None:
            self.ulog.close()

    def write_errors(self) -> list[tuple[Path, OSError]]:
        """The vehicle's logs that could not be written (a full disk), with why."""
        return [(w.path, w.error) for w in (self.tlog, self.ulog) if w is not None and w.error is not None]


def attach_mavlink(
    ap: Autopilot,
    ports: PortsConfig,
    run_dir: Path | None,
    signing: SigningConfig | None,
    hub: MavlinkHub | None = None,
    firmware: Firmware = Firmware.PX4,
    trust_unsigned: Callable[[bool, tuple[str, int]], bool] | None = None,
) -> AttachedMavlink:
    """The MAVLink server (and tlog, stored parameters) of ``ap``, served by ``hub`` (or a thread of its own),
    presenting ``firmware``'s personality, on the hub's wall clock; with ``signing``, unsigned frames are
    obeyed only from peers ``trust_unsigned`` accepts (the run's own processes, ``runlocal.py``)."""
    clock = hub.clock if hub is not None else WALL
    tlog = ulog = None
    if run_dir is not None:
        tlog = TlogWriter(run_dir / f"vehicle-{ap.vehicle}.tlog", clock=clock)
        for refused in persist_params(ap.params, run_dir, ap.vehicle):
            log.warning("vehicle %d: stored parameter not restored: %s", ap.vehicle, refused)
        ulog = ap.flight_log = FlightLog(
            run_dir / f"vehicle-{ap.vehicle}.ulg", ap.params, ap.vehicle, clock.unix_ns() // 1000
        )
    server = MavlinkServer(
        ap,
        ap.vehicle,
        ports,
        signing,
        clock=clock,
        tap=tlog.write if tlog else None,
        firmware=firmware,
        trust_unsigned=trust_unsigned,
    )
    own = server.dialect.own_params  # a personality's own table (ArduCopter's names)
    if run_dir is not None and own is not None:
        for refused in persist_params(own, run_dir, ap.vehicle, firmware.value):
            log.warning("vehicle %d: stored parameter not restored: %s", ap.vehicle, refused)
    if hub is None:
        server.start()
    else:
        hub.add(server)
    return AttachedMavlink(server, tlog, ulog)


def close_mavlink(hub: MavlinkHub, attached: Sequence[AttachedMavlink]) -> None:
    """Stop ``hub`` first, then close each vehicle's MAVLink side: a server leaving a running hub waits for
    its thread (which serves every other vehicle meanwhile), one after the other: seconds for fifty."""
    hub.stop()
    for handle in attached:
        handle.close()


def vehicle_ports(
    base: PortsConfig,
    firmware: Firmware,
    tcp_port_base: int,
    tcp_port_step: int,
    extra: tuple[int, ...],
    tcp_sim_clients: bool = False,
) -> PortsConfig:
    """A vehicle's ports. ArduPilot vehicles add SERIAL0 on TCP and the extra UDP outputs ArduPilot users expect,
    and send nothing unasked to PX4's script port 14540 + i (a PX4 script there must not find an ArduCopter)."""
    if firmware is not Firmware.ARDUPILOT:
        return base
    return dataclasses.replace(
        base,
        api_port_base=0,
        tcp_port_base=tcp_port_base,
        tcp_port_step=tcp_port_step,
        gcs_extra_ports=extra,
        tcp_sim_clients=tcp_sim_clients,
    )


def _physics(path: Path, vehicles: Sequence[int]) -> Physics:
    """The physics of ``vehicles`` as ``harness run`` configured the whole run in ``path``."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ScenarioError(f"--physics {path}: cannot read it ({exc.strerror})") from None
    return Physics(PhysicsConfig.from_json(data), vehicles)


def _config_from_flags(a: argparse.Namespace) -> AutopilotProcessConfig:
    """The configuration the flags of a hand-started process give (ValueError / ScenarioError when bad)."""
    return AutopilotProcessConfig(
        address=a.address,
        vehicles=tuple(int(v) for v in a.vehicles.split(",") if v.strip()),
        api_port_base=a.api_port_base,
        api_local_port_base=a.api_local_port_base,
        gcs_port=a.gcs_port,
        run_dir=str(a.run_dir) if a.run_dir is not None else None,
        params={int(k): v for k, v in json.loads(a.params).items()},
        signing_key_file=str(a.signing_key_file) if a.signing_key_file is not None else None,
        trust_run=a.trust_run,
        ground_truth=a.ground_truth,
        firmware=tuple(Firmware.parse(f, "--firmware") for f in a.firmware.split(",") if f.strip()),
        tcp_port_base=a.tcp_port_base,
        tcp_port_step=a.tcp_port_step,
        gcs_extra_ports=tuple(int(p) for p in a.gcs_extra_ports.split(",") if p.strip()),
        tcp_sim_clients=a.tcp_sim_clients,
        physics=str(a.physics) if a.physics is not None else None,
        name=a.name,
    )


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m harness.autopilot.sitl", description=__doc__)
    ap.add_argument(
        "--config", type=Path, default=None, metavar="FILE", help="all of the below, as harness run writes it"
    )
    ap.add_argument("--address", help="channel address")
    ap.add_argument("--vehicles", help="comma-separated vehicle indices")
    ap.add_argument("--api-port-base", type=int, default=14540, help="send to this port + i (0: only to peers)")
    ap.add_argument("--api-local-port-base", type=int, default=0, help="listen on this port + i (0: any free port)")
    ap.add_argument("--gcs-port", type=int, default=14550)
    ap.add_argument("--run-dir", type=Path, default=None, help="write vehicle-<i>.tlog here")
    ap.add_argument("--params", default="{}", help='JSON: {"<vehicle>": {"PARAM": value}}')
    ap.add_argument(
        "--signing-key-file", type=Path, default=None, help="MAVLink 2 signing: file with the key as 64 hex digits"
    )
    ap.add_argument(
        "--trust-run", type=int, default=0, metavar="PID", help="with signing: obey unsigned frames from PID's children"
    )
    ap.add_argument("--ground-truth", action="store_true")
    ap.add_argument("--firmware", default="px4", help="px4 or ardupilot: one for all, or comma-separated per vehicle")
    ap.add_argument("--tcp-port-base", type=int, default=0, help="ArduPilot vehicles listen on TCP base + step*i")
    ap.add_argument("--tcp-port-step", type=int, default=1)
    ap.add_argument("--gcs-extra-ports", default="", help="comma-separated extra UDP outputs of ArduPilot vehicles")
    ap.add_argument("--tcp-sim-clients", action="store_true", help="TCP clients are missions on sim time (a run)")
    ap.add_argument(
        "--physics",
        type=Path,
        default=None,
        metavar="FILE",
        help="step these vehicles' physics here too, configured by FILE (JSON, written by harness run)",
    )
    ap.add_argument("--name", default=None, help="this process's name in the channel")
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    lifeline.hold_on()  # started by a run (Children): die with it, before anything else
    ap = _parser()
    a = ap.parse_args(argv)
    if a.config is None and (a.address is None or a.vehicles is None):
        ap.error("give --config FILE, or --address and --vehicles")
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        cfg = AutopilotProcessConfig.read(a.config) if a.config is not None else _config_from_flags(a)
    except (ValueError, json.JSONDecodeError) as exc:
        log.error("autopilot process: bad argument: %s", exc)
        return 2
    except HarnessError as exc:  # a configuration that is not one, an unknown firmware: one line, no traceback
        log.error("autopilot process: %s", exc)
        return 2
    return serve(cfg)


def serve(cfg: AutopilotProcessConfig) -> int:
    """Run the autopilots of ``cfg`` until the run ends: 0, 1 on a failed run, 2 on a bad configuration."""
    vehicles = list(cfg.vehicles)
    try:
        signing = (
            SigningConfig(read_signing_key(Path(cfg.signing_key_file), "--signing-key-file"))
            if cfg.signing_key_file
            else None
        )
        physics = _physics(Path(cfg.physics), vehicles) if cfg.physics is not None else None
    except HarnessError as exc:  # a bad signing key file, an unreadable physics file: one line, no traceback
        log.error("autopilot process: %s", exc)
        return 2
    base = PortsConfig(
        api_port_base=cfg.api_port_base, api_local_port_base=cfg.api_local_port_base, gcs_port=cfg.gcs_port
    )
    trust = RunLocalPeers(cfg.trust_run) if cfg.trust_run else None
    run_dir = Path(cfg.run_dir) if cfg.run_dir is not None else None

    def config_for(v: int) -> AutopilotConfig:
        fw = firmware_of(cfg.firmware, v)
        params = {**core_param_defaults(fw), **cfg.params.get(v, {})}
        return AutopilotConfig(vehicle=v, use_ground_truth=cfg.ground_truth, params=params)

    hub = MavlinkHub()
    attached: list[AttachedMavlink] = []
    try:
        aps = make_autopilots(vehicles, config_for)
        for v, autopilot in aps.items():
            fw = firmware_of(cfg.firmware, v)
            ports = vehicle_ports(
                base, fw, cfg.tcp_port_base, cfg.tcp_port_step, cfg.gcs_extra_ports, cfg.tcp_sim_clients
            )
            attached.append(attach_mavlink(autopilot, ports, run_dir, signing, hub, fw, trust))
        hub.start()  # once every server is in: an add to a running hub waits for its thread
        sent = {h.server.vehicle: h.server.sent_to_missions for h in attached}
        run_autopilots(cfg.address, vehicles, autopilots=aps, name=cfg.name, physics=physics, mavlink_sent=sent)
    except HarnessError as exc:
        log.error("%s", exc)
        return 1
    finally:
        close_mavlink(hub, attached)
    failed = [(path, why) for handle in attached for path, why in handle.write_errors()]
    for path, why in failed:
        log.error("could not write %s: %s; the recording is incomplete", path, why.strerror)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
