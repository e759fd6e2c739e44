"""The autopilot's ``camera`` service: a survey camera as PX4 SITL's simulated MAVLink camera presents one, taking
geotagged pictures in lockstep (the MAVLink camera protocol, ``harness.autopilot.mavlink.camera``, speaks for it).

A picture is a capture event: the ground truth of the vehicle at the tick it is taken (position, altitude AMSL and
above home, attitude; the camera is fixed to the body and looks along it, as PX4's ``camera_feedback`` reports the
vehicle's attitude without a gimbal), an index from 0 and a file name. No image is rendered: the recordings show
each capture point and the camera's frustum (``world.mcap`` ``/sim/events`` kind ``capture``, the 3D view).

Captures come from commands (one picture, or every ``interval`` seconds, ``total`` of them or until stopped; video
start and stop) and from the mission: ``DO_SET_CAM_TRIGG_DIST`` (a picture each time the vehicle has moved that
far horizontally from the last one, as PX4's ``camera_trigger`` distance mode does; param3 = 1 takes one at once),
``IMAGE_START_CAPTURE`` / ``IMAGE_STOP_CAPTURE`` and the video items, all re-issued by the mission as PX4 does.

A camera nobody uses costs one attribute test per step (``active``).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field

import msgspec

from harness.autopilot.api import CommandResult, MavCmd, MissionItem
from harness.fdm.frame import Truth

MODE_IMAGE, MODE_VIDEO = 0, 1


class Capture(msgspec.Struct, array_like=True, frozen=True, tag="capture"):
    """One picture: where and how the camera was at the instant (ground truth)."""

    index: int
    t_ns: int
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    relative_alt_m: float
    pos_ned_m: tuple[float, float, float]
    q: tuple[float, float, float, float]
    """Camera attitude (w, x, y, z), body to NED: the vehicle's."""

    @property
    def file_url(self) -> str:
        return f"sim://camera/IMG_{self.index:05d}.jpg"


@dataclass(slots=True)
class CameraState:
    mode: int = MODE_IMAGE
    interval_ns: int = 0
    """Time-lapse interval (0: none)."""
    remaining: int = 0
    """Pictures still to take in the time-lapse (0 = until stopped)."""
    next_ns: int | None = None
    trigger_dist_m: float = 0.0
    last_ne: tuple[float, float] | None = None
    """Where the last distance-triggered picture was taken (north, east)."""
    once: int = 0
    """Pictures to take at the next step."""
    video_since_ns: int | None = None
    captures: list[Capture] = field(default_factory=list)


class CameraDevice:
    """One vehicle's camera. Commands may come from any thread; ``step`` runs in ``Autopilot.step`` under the
    autopilot's lock."""

    def __init__(self, lock: threading.Lock) -> None:
        self._lock = lock
        self.s = CameraState()
        self.active = False
        """Something to do at the next steps (a picture due, a time-lapse, a trigger distance, a video)."""
        self.new: list[Capture] = []
        """Captures the MAVLink side has not sent yet."""
        self.recorded: list[Capture] = []
        """Captures the recordings have not had yet (END-TICK-AC ``events``)."""
        self.home_alt_m = 0.0

    # ------------------------------------------------------------------ commands (any thread)
    def set_mode(self, mode: int) -> CommandResult:
        if mode not in (MODE_IMAGE, MODE_VIDEO):
            return CommandResult.denied(f"camera: no mode {mode} (0 image, 1 video)")
        with self._lock:
            if self.s.video_since_ns is not None or self.s.interval_ns:
                return CommandResult.denied("camera: busy (capturing)")
            self.s.mode = mode
        return CommandResult.accepted()

    def start_capture(self, interval_s: float, total: int) -> CommandResult:
        """IMAGE_START_CAPTURE: ``total`` pictures (0 = until stopped) every ``interval_s`` (one picture: total 1)."""
        if not math.isfinite(interval_s) or interval_s < 0 or total < 0:
            return CommandResult.denied("camera: bad interval or count")
        with self._lock:
            s = self.s
            if s.mode != MODE_IMAGE:
                return CommandResult.denied("camera: not in image mode")
            if total == 1:
                s.once += 1
            else:
                if interval_s <= 0:
                    return CommandResult.denied("camera: a time-lapse needs an interval > 0")
                s.interval_ns = round(interval_s * 1e9)
                s.remaining = total
                s.next_ns = None
            self._update()
        return CommandResult.accepted()

    def stop_capture(self) -> CommandResult:
        with self._lock:
            self.s.interval_ns = 0
            self.s.remaining = 0
            self._update()
        return CommandResult.accepted()

    def video(self, on: bool, t_ns: int) -> CommandResult:
        with self._lock:
            s = self.s
            if on and s.mode != MODE_VIDEO:
                return CommandResult.denied("camera: not in video mode")
            s.video_since_ns = t_ns if on else None
            self._update()
        return CommandResult.accepted()

    def set_trigger_distance(self, dist_m: float, trigger_now: bool) -> CommandResult:
        """DO_SET_CAM_TRIGG_DIST: a picture every ``dist_m`` metres travelled (0 stops)."""
        if not math.isfinite(dist_m) or dist_m < 0:
            return CommandResult.denied("camera: trigger distance must be >= 0")
        with self._lock:
            self._trigger_distance(dist_m, trigger_now)
        return CommandResult.accepted()

    def _trigger_distance(self, dist_m: float, trigger_now: bool) -> None:
        s = self.s
        s.trigger_dist_m = dist_m
        s.last_ne = None  # the next step takes the reference (and the first picture: PX4 shoots on activation)
        if trigger_now and dist_m == 0:
            s.once += 1
        self._update()

    def format_storage(self) -> CommandResult:
        with self._lock:
            self.s.captures.clear()
        return CommandResult.accepted()

    def _update(self) -> None:
        s = self.s
        self.active = bool(s.once or s.interval_ns or s.trigger_dist_m or s.video_since_ns is not None)

    # ------------------------------------------------------------------ state (any thread)
    def state(self) -> CameraState:
        return self.s

    def captures(self) -> list[Capture]:
        with self._lock:
            return list(self.s.captures)

    def take_new(self) -> list[Capture]:
        with self._lock:
            new, self.new = self.new, []
        return new

    # ------------------------------------------------------------------ the mission (stepping thread, under the lock)
    def mission_item(self, it: MissionItem, t_ns: int) -> None:
        cmd = it.command
        if cmd == MavCmd.DO_SET_CAM_TRIGG_DIST:
            self._trigger_distance(max(0.0, float(it.param1)), float(it.param3) == 1.0)
        elif cmd == MavCmd.IMAGE_START_CAPTURE:
            s = self.s
            total = max(0, int(it.param3))
            if total == 1:
                s.once += 1
            elif it.param2 > 0:
                s.interval_ns, s.remaining, s.next_ns = round(float(it.param2) * 1e9), total, None
        elif cmd == MavCmd.IMAGE_STOP_CAPTURE:
            self.s.interval_ns = self.s.remaining = 0
        elif cmd == MavCmd.VIDEO_START_CAPTURE:
            self.s.mode, self.s.video_since_ns = MODE_VIDEO, t_ns
        elif cmd == MavCmd.VIDEO_STOP_CAPTURE:
            self.s.video_since_ns = None
        self._update()

    # ------------------------------------------------------------------ the tick (stepping thread, under the lock)
    def step(self, t_ns: int, truth: Truth, airborne: bool) -> None:
        s = self.s
        shots = s.once
        s.once = 0
        if s.interval_ns:
            if s.next_ns is None:
                s.next_ns = t_ns
            if t_ns >= s.next_ns:
                shots += 1
                s.next_ns += s.interval_ns
                if s.remaining:
                    s.remaining -= 1
                    if s.remaining == 0:
                        s.interval_ns = 0
        if s.trigger_dist_m and airborne:
            n, e, _ = truth.pos_ned_m
            last = s.last_ne
            if last is None or math.hypot(n - last[0], e - last[1]) >= s.trigger_dist_m:
                s.last_ne = (n, e)
                shots += 1
        for _ in range(shots):
            c = Capture(
                len(s.captures),
                t_ns,
                truth.lat_deg,
                truth.lon_deg,
                truth.alt_amsl_m,
                truth.alt_amsl_m - self.home_alt_m,
                truth.pos_ned_m,
                truth.quat,
            )
            s.captures.append(c)
            self.new.append(c)
            self.recorded.append(c)
        self._update()
