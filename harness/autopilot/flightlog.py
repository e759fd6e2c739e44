"""Each vehicle's flight log, the PX4 way: a ULog file (``harness.autopilot.ulog``) with PX4's topic and field
names, timestamps in µs of sim time since the vehicle started (PX4's boot time), written from boot until
the run ends (PX4's ``SDLOG_MODE`` 2).

Topics: ``vehicle_attitude``, ``vehicle_local_position``, ``sensor_combined``, ``actuator_outputs`` at
50 Hz, ``vehicle_global_position`` at 10 Hz, ``battery_status`` and ``vehicle_status`` at 2 Hz and on
change; every parameter at the start ('P'); every status text as a logged string ('L'). PX4 Flight Review,
PlotJuggler and pyulog read it. The MAVLink log protocol (``harness.autopilot.mavlink.logs``) serves it.
"""

from __future__ import annotations

import contextlib
import math
import threading
from pathlib import Path
from typing import BinaryIO, Protocol

from harness.autopilot.api import FlightMode, Severity
from harness.autopilot.params import Params, ParamType
from harness.autopilot.supervisor import Supervised
from harness.autopilot.ulog import Topic, UlogWriter

_NO_ORIGIN = (math.nan, math.nan, math.nan)
_UNUSED_OUTPUTS = (0.0,) * 12
FAST_NS = 20_000_000
MEDIUM_NS = 100_000_000
SLOW_NS = 500_000_000

TOPICS = (
    Topic("vehicle_attitude", [("uint64_t", "timestamp"), ("float[4]", "q")]),
    Topic(
        "vehicle_local_position",
        [("uint64_t", "timestamp")]
        + [("float", n) for n in ("x", "y", "z", "vx", "vy", "vz", "ax", "ay", "az", "heading")]
        + [("double", "ref_lat"), ("double", "ref_lon"), ("float", "ref_alt")]
        + [("bool", n) for n in ("xy_valid", "z_valid", "v_xy_valid", "v_z_valid")],
    ),
    Topic(
        "sensor_combined",
        [
            ("uint64_t", "timestamp"),
            ("float[3]", "gyro_rad"),
            ("uint32_t", "gyro_integral_dt"),
            ("int32_t", "accelerometer_timestamp_relative"),
            ("float[3]", "accelerometer_m_s2"),
            ("uint32_t", "accelerometer_integral_dt"),
        ],
    ),
    Topic("actuator_outputs", [("uint64_t", "timestamp"), ("uint32_t", "noutputs"), ("float[16]", "output")]),
    Topic(
        "vehicle_global_position",
        [("uint64_t", "timestamp"), ("double", "lat"), ("double", "lon"), ("float", "alt"), ("float", "eph")],
    ),
    Topic(
        "battery_status",
        [
            ("uint64_t", "timestamp"),
            ("float", "voltage_v"),
            ("float", "current_a"),
            ("float", "discharged_mah"),
            ("float", "remaining"),
            ("uint8_t", "cell_count"),
            ("bool", "connected"),
        ],
    ),
    Topic(
        "vehicle_status",
        [
            ("uint64_t", "timestamp"),
            ("uint8_t", "arming_state"),
            ("uint8_t", "nav_state"),
            ("bool", "failsafe"),
            ("uint8_t", "vehicle_type"),
        ],
    ),
)

NAV_STATE: dict[FlightMode, int] = {
    FlightMode.MANUAL: 0,
    FlightMode.ALTCTL: 1,
    FlightMode.POSCTL: 2,
    FlightMode.MISSION: 3,
    FlightMode.HOLD: 4,
    FlightMode.RTL: 5,
    FlightMode.OFFBOARD: 14,
    FlightMode.STABILIZED: 15,
    FlightMode.TAKEOFF: 17,
    FlightMode.LAND: 18,
    FlightMode.FOLLOW_TARGET: 19,
    FlightMode.ORBIT: 21,
}
"""PX4's ``vehicle_status.nav_state`` for each mode."""

_LEVEL = {Severity.EMERGENCY: 0, Severity.ALERT: 1, Severity.CRITICAL: 2, Severity.ERROR: 3, Severity.WARNING: 4}


class FlightLog:
    """The ULog of one vehicle, written to ``path`` (appending whole messages; see :meth:`flush`)."""

    def __init__(self, path: Path, params: Params, vehicle: int, start_unix_us: int) -> None:
        self.path = path
        self.start_unix_us = start_unix_us
        self._f: BinaryIO = path.open("wb")
        w = self._w = UlogWriter(0)
        w.info("sys_name", "PX4")
        w.info("ver_hw", "SITL_UAV_HARNESS")
        w.info("ver_sw", "uav-harness")
        w.info("sys_mcu", "uav-harness JSBSim SITL")
        w.info("sys_uuid", f"uav-harness-vehicle-{vehicle}")
        w.info("time_ref_utc", 0)
        for d in params.defs:
            v = params.get(d.name)
            w.param(d.name, int(v) if d.type == ParamType.INT32 else float(v))
        w.add_topics(TOPICS)
        self._next = {FAST_NS: 0, MEDIUM_NS: 0, SLOW_NS: 0}
        self._status: tuple[object, ...] = ()
        self.closed = False
        self.error: OSError | None = None
        self._size = 0
        """Bytes written (the file's size: it was created empty)."""

    def text(self, t_ns: int, severity: Severity, text: str) -> None:
        if not self.closed:
            self._w.log(_LEVEL.get(severity, 6), max(t_ns, 0) // 1000, text)

    def record(self, ap: Supervised) -> None:
        """After a step (under the autopilot's lock): the samples that fall due at this sim time."""
        c = ap.core
        t = c.t_ns
        if t < 0 or self.closed:
            return
        nxt = self._next
        us = t // 1000
        w = self._w
        e = c.est
        status = (c.armed, c.mode, bool(ap.failsafe))
        if t >= nxt[FAST_NS]:
            nxt[FAST_NS] = t + FAST_NS
            data = w.data
            data("vehicle_attitude", (us, *e.q))
            ref = e.ref
            valid = e.pos_valid
            hv = e.height_valid
            if ref is not None:
                origin = (math.degrees(ref.lat_rad), math.degrees(ref.lon_rad), ref.alt_m)
            else:
                origin = _NO_ORIGIN
            data(
                "vehicle_local_position",
                (us, e.pn, e.pe, e.pd, e.vn, e.ve, e.vd, 0.0, 0.0, e.acc_d, e.yaw, *origin, valid, hv, valid, hv),
            )
            data("sensor_combined", (us, *e.rates, 4000, 0, *e.accel_body, 4000))
            data("actuator_outputs", (us, 4, *c.motors, *_UNUSED_OUTPUTS))
        if t >= nxt[MEDIUM_NS]:
            nxt[MEDIUM_NS] = t + MEDIUM_NS
            lat, lon, alt = e.geo()
            g = e.gps
            w.data("vehicle_global_position", (us, lat, lon, alt, g.eph_m if g is not None else 99.0))
        if t >= nxt[SLOW_NS] or status != self._status:
            if t >= nxt[SLOW_NS]:
                nxt[SLOW_NS] = t + SLOW_NS
                b = c.battery
                cells = int(ap.params["BAT_N_CELLS"])
                w.data("battery_status", (us, b.voltage_v, b.current_a, b.consumed_mah, b.remaining, cells, True))
            self._status = status
            w.data("vehicle_status", (us, 2 if c.armed else 1, NAV_STATE.get(c.mode, 4), bool(ap.failsafe), 2))
        if w.pending > 65536:
            self.flush()

    def flush(self) -> int:
        """Write what is buffered; the file's size, which ends on a message boundary. A write that fails (a
        full disk) closes the log and is kept in :attr:`error`: the vehicle flies on, the run reports it."""
        if not self.closed:
            data = self._w.take()
            try:
                self._f.write(data)
                self._f.flush()
                self._size += len(data)
            except OSError as exc:
                self.error, self.closed = exc, True
                with contextlib.suppress(OSError):
                    self._f.close()
        return self._size

    def close(self) -> None:
        if not self.closed:
            self.flush()
            if not self.closed:
                self.closed = True
                self._f.close()


class _LogOwner(Protocol):
    lock: threading.Lock
    flight_log: FlightLog | None


class FlightLogFiles:
    """The autopilot's ``log_files`` service: the flight logs to offer over MAVLink."""

    def __init__(self, ap: _LogOwner) -> None:
        self.ap = ap

    def files(self) -> list[tuple[Path, int, int]]:
        """(path, size in bytes up to the last whole message, start time in Unix seconds) of each log; the log
        being written is flushed first; none while the run writes no log."""
        with self.ap.lock:
            fl = self.ap.flight_log
            if fl is None:
                return []
            return [(fl.path, fl.flush(), fl.start_unix_us // 1_000_000)]
