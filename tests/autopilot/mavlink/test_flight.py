"""Flying through MAVLink only: a real Autopilot and the test quad model stepped in a thread at up to 4x
real time; the ground station arms, takes off, repositions, flies offboard, and lands."""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import FlightMode, LandedState
from harness.core.clock import real_monotonic_ns
from tests.autopilot.mavlink.conftest import Gcs, Rig

M = mavlink2
ARMED = M.MAV_MODE_FLAG_SAFETY_ARMED


def _mode(hb: object) -> FlightMode | None:
    return FlightMode.from_custom_mode(hb.custom_mode)  # type: ignore[attr-defined]


def _take_off(gcs: Gcs, rig: Rig) -> None:
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0).result == M.MAV_RESULT_ACCEPTED
    assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, math.nan).result == 0
    hb = gcs.recv("HEARTBEAT", 2.0, lambda m: _mode(m) is FlightMode.TAKEOFF)
    assert hb.base_mode & ARMED and hb.system_status == M.MAV_STATE_ACTIVE
    assert gcs.recv("EXTENDED_SYS_STATE", 10.0, lambda m: m.landed_state == M.MAV_LANDED_STATE_IN_AIR)
    gcs.recv("HEARTBEAT", 20.0, lambda m: _mode(m) is FlightMode.HOLD)


def test_takeoff_uses_mis_takeoff_alt_then_land_and_auto_disarm(gcs: Gcs, flying_rig: Rig) -> None:
    gcs.send(gcs.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 4.0, M.MAV_PARAM_TYPE_REAL32))
    gcs.recv("PARAM_VALUE", cond=lambda m: m.param_id == "MIS_TAKEOFF_ALT")
    _take_off(gcs, flying_rig)
    pos = gcs.recv("GLOBAL_POSITION_INT", 2.0)
    assert abs(pos.relative_alt / 1000.0 - 4.0) < 0.5
    assert abs(-flying_rig.sim.pos[2] - 4.0) < 0.5
    assert gcs.command(M.MAV_CMD_NAV_LAND).result == M.MAV_RESULT_ACCEPTED
    gcs.recv("HEARTBEAT", 2.0, lambda m: _mode(m) is FlightMode.LAND)
    gcs.recv("EXTENDED_SYS_STATE", 20.0, lambda m: m.landed_state == M.MAV_LANDED_STATE_ON_GROUND)
    hb = gcs.recv("HEARTBEAT", 10.0, lambda m: not m.base_mode & ARMED)
    assert hb.system_status == M.MAV_STATE_STANDBY
    assert flying_rig.sim.on_ground


def test_time_boot_ms_never_goes_back_and_streams_follow_the_faster_clock(gcs: Gcs, flying_rig: Rig) -> None:
    t0 = real_monotonic_ns()
    sim0 = flying_rig.ap.telemetry.state().t_ns
    msgs = [m for _, m in gcs.collect(2.0, {"GLOBAL_POSITION_INT"})]
    wall_s = (real_monotonic_ns() - t0) / 1e9
    speed = (flying_rig.ap.telemetry.state().t_ns - sim0) / 1e9 / wall_s
    stamps = [m.time_boot_ms for m in msgs]
    assert stamps == sorted(stamps)
    rate_hz = len(msgs) / wall_s
    # 10 Hz of sim time at `speed` x real time, at least 10 Hz of wall time
    assert rate_hz >= 0.7 * max(10.0, 10.0 * min(speed, 8.0)), (rate_hz, speed)


def test_reposition_command_int_and_orbit(gcs: Gcs, flying_rig: Rig) -> None:
    _take_off(gcs, flying_rig)
    state = flying_rig.ap.telemetry.state()
    assert state.home is not None
    lat = state.home.lat_deg + 10.0 / 111_195.0
    ack = gcs.command_int(
        M.MAV_CMD_DO_REPOSITION,
        M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        -1,
        1,
        0,
        math.nan,
        round(lat * 1e7),
        round(state.home.lon_deg * 1e7),
        6.0,
    )
    assert ack.result == M.MAV_RESULT_ACCEPTED
    deadline = real_monotonic_ns() + 15_000_000_000
    while real_monotonic_ns() < deadline and abs(flying_rig.sim.pos[0] - 10.0) > 0.5:
        gcs.collect(0.2)
    n, e, d = flying_rig.sim.pos
    assert abs(n - 10.0) < 0.7 and abs(e) < 0.7 and abs(-d - 6.0) < 0.7
    # exactly what MAVSDK's do_orbit(5, 2, ..., NaN, NaN, NaN) sends: COMMAND_INT, frame GLOBAL_RELATIVE_ALT,
    # x = y = int32(round(NaN * 1e7)) = INT32_MIN on x86, z NaN (centre = here)
    int32_min = -(2**31)
    ack = gcs.command_int(M.MAV_CMD_DO_ORBIT, 3, 5.0, 2.0, 0, math.nan, int32_min, int32_min, math.nan)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    t_orbit = flying_rig.ap.telemetry.state().t_ns
    deadline = real_monotonic_ns() + 8_000_000_000
    while real_monotonic_ns() < deadline and flying_rig.ap.telemetry.state().t_ns - t_orbit < 15_000_000_000:
        gcs.collect(0.2)  # 15 s of sim time in orbit (at most 8 s of wall time)
    n, e, _ = flying_rig.sim.pos
    assert abs(math.hypot(n - 10.0, e) - 5.0) < 1.5, "orbits 5 m around where it was"
    assert flying_rig.ap.telemetry.state().mode is FlightMode.ORBIT


def test_offboard_needs_setpoints_and_falls_back_when_they_stop(gcs: Gcs, flying_rig: Rig) -> None:
    _take_off(gcs, flying_rig)
    assert gcs.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == M.MAV_RESULT_DENIED
    mask = 0b0000_1001_1100_0111  # velocity and yaw (ignore position, acceleration, yaw rate), as MAVSDK
    n0 = flying_rig.sim.pos[0]

    def stream(seconds: float) -> list[object]:
        """Setpoints every 50 ms of wall time (like MAVSDK); returns the heartbeats seen meanwhile."""
        end = real_monotonic_ns() + int(seconds * 1e9)
        beats = []
        while real_monotonic_ns() < end:
            gcs.send(
                gcs.mav.set_position_target_local_ned_encode(
                    0, 1, 1, M.MAV_FRAME_LOCAL_NED, mask, 0, 0, 0, 1.0, 0, 0, 0, 0, 0, 0.0, 0
                )
            )
            beats += [m for _, m in gcs.collect(0.05, {"HEARTBEAT"})]
        return beats

    stream(0.3)
    assert gcs.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == M.MAV_RESULT_ACCEPTED
    beats = stream(2.5)
    assert any(_mode(hb) is FlightMode.OFFBOARD for hb in beats), "heartbeat shows OFFBOARD within 3 s"
    assert flying_rig.sim.pos[0] - n0 > 2.0, "flew north at 1 m/s"
    assert flying_rig.server.counters().setpoints_refused == 0
    # a refused setpoint (part of a vector masked) is counted and explained
    gcs.send(gcs.mav.set_position_target_local_ned_encode(0, 1, 1, 1, 0b110, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))
    assert "part of a vector" in gcs.recv("STATUSTEXT", 2.0, lambda m: "vector" in m.text).text
    # setpoints stop: the autopilot holds (COM_OBL_RC_ACT 5) within its wall-clock loss timeout
    hb = gcs.recv("HEARTBEAT", 4.0, lambda m: _mode(m) is not FlightMode.OFFBOARD)
    assert _mode(hb) is FlightMode.HOLD
    assert flying_rig.ap.telemetry.state().landed_state == LandedState.IN_AIR


def test_a_takeoff_altitude_below_the_minimum_is_raised_to_it_as_px4_does(gcs: Gcs, flying_rig: Rig) -> None:
    """MAVProxy's ``takeoff 10`` sends 10 m AMSL, below home here: PX4 takes off to home + MIS_TAKEOFF_ALT and
    says so ("Using minimum takeoff altitude"), it does not refuse."""
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0).result == M.MAV_RESULT_ACCEPTED
    home = flying_rig.ap.telemetry.state().home
    assert home is not None
    ack = gcs.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, home.alt_amsl_m - 5.0)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    text = gcs.recv("STATUSTEXT", 2.0, lambda m: "minimum takeoff" in m.text)
    assert text.text == "Using minimum takeoff altitude: 2.50 m" and text.severity == M.MAV_SEVERITY_CRITICAL
    gcs.recv("HEARTBEAT", 20.0, lambda m: _mode(m) is FlightMode.HOLD)
    assert abs(-flying_rig.sim.pos[2] - 2.5) < 0.5
