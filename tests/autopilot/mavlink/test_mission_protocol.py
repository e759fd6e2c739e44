"""Mission protocol over real UDP: upload / download round trips for missions, fences and rally points,
retries on the wall clock, clear, set current; then a flown mission reports every item reached."""

from __future__ import annotations

import functools

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from harness.autopilot.api import MissionKind
from harness.core.clock import real_monotonic_ns
from tests.autopilot.mavlink.conftest import Gcs, Rig

M = mavlink2
LAT0, LON0 = 47.397742, 8.545594
REL = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


def _items(kind: int) -> list[tuple[int, int, float, float, float, float, int, int, float]]:
    """(frame, command, p1..p4, x, y, z) per item."""
    if kind == 0:
        return [
            (REL, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, float("nan"), int(LAT0 * 1e7), int(LON0 * 1e7), 5.0),
            (REL, M.MAV_CMD_NAV_WAYPOINT, 0, 1.5, 0, float("nan"), int((LAT0 + 5e-5) * 1e7), int(LON0 * 1e7), 6.0),
            (M.MAV_FRAME_MISSION, M.MAV_CMD_DO_CHANGE_SPEED, 1, 3.0, -1, 0, 0, 0, 0.0),
            (
                REL,
                M.MAV_CMD_NAV_WAYPOINT,
                0,
                0,
                0,
                float("nan"),
                int((LAT0 + 5e-5) * 1e7),
                int((LON0 + 7e-5) * 1e7),
                6.0,
            ),
            (REL, M.MAV_CMD_NAV_LAND, 0, 0, 0, float("nan"), int((LAT0 + 5e-5) * 1e7), int((LON0 + 7e-5) * 1e7), 0.0),
        ]
    if kind == 1:
        pts = [(0, 0), (0, 4e-4), (4e-4, 4e-4), (4e-4, 0)]
        poly = [
            (M.MAV_FRAME_GLOBAL_INT, 5001, 4, 0, 0, 0, int((LAT0 + a) * 1e7), int((LON0 + b) * 1e7), 0.0)
            for a, b in pts
        ]
        return [*poly, (M.MAV_FRAME_GLOBAL_INT, 5004, 20.0, 0, 0, 0, int(LAT0 * 1e7), int(LON0 * 1e7), 0.0)]
    return [(REL, 5100, 0, 0, 0, 0, int((LAT0 + 1e-4) * 1e7), int(LON0 * 1e7), 15.0)]


def upload(gcs: Gcs, kind: int, items: list, drop_first_request: bool = False) -> object:
    gcs.send(gcs.mav.mission_count_encode(1, 1, len(items), kind))
    dropped = not drop_first_request
    while True:
        m = gcs.recv("MISSION_REQUEST_INT", 4.0)
        if not dropped:
            dropped = True  # ignore it: the vehicle must ask again after its wall-clock timeout
            continue
        assert m.mission_type == kind and m.target_system == 245
        f, c, p1, p2, p3, p4, x, y, z = items[m.seq]
        gcs.send(gcs.mav.mission_item_int_encode(1, 1, m.seq, f, c, 0, 1, p1, p2, p3, p4, x, y, z, kind))
        if m.seq == len(items) - 1:
            return gcs.recv("MISSION_ACK", 3.0, lambda a: a.mission_type == kind)


def _is_seq(seq: int, m: object) -> bool:
    return bool(m.seq == seq)  # type: ignore[attr-defined]


def download(gcs: Gcs, kind: int) -> list:
    gcs.send(gcs.mav.mission_request_list_encode(1, 1, kind))
    count = gcs.recv("MISSION_COUNT", 3.0, lambda m: m.mission_type == kind).count
    got = []
    for seq in range(count):
        gcs.send(gcs.mav.mission_request_int_encode(1, 1, seq, kind))
        got.append(gcs.recv("MISSION_ITEM_INT", 3.0, functools.partial(_is_seq, seq)))
    gcs.send(gcs.mav.mission_ack_encode(1, 1, M.MAV_MISSION_ACCEPTED, kind))
    return got


def _same(item: tuple, m: object) -> bool:
    f, c, p1, p2, p3, p4, x, y, z = item
    vals = (m.frame, m.command, m.param1, m.param2, m.param3, m.param4, m.x, m.y, m.z)  # type: ignore[attr-defined]
    return vals == pytest.approx((f, c, p1, p2, p3, p4, x, y, z), nan_ok=True)


@pytest.mark.parametrize("kind", [0, 1, 2])
def test_upload_download_round_trip(gcs: Gcs, idle_rig: Rig, kind: int) -> None:
    items = _items(kind)
    ack = upload(gcs, kind, items)
    assert ack.type == M.MAV_MISSION_ACCEPTED  # type: ignore[attr-defined]
    assert len(idle_rig.ap.mission.download(MissionKind(kind))) == len(items)
    back = download(gcs, kind)
    assert len(back) == len(items)
    assert all(_same(i, m) for i, m in zip(items, back, strict=True))
    assert all(m.mission_type == kind for m in back)


def test_upload_retries_a_lost_request_and_clear_all(gcs: Gcs, idle_rig: Rig) -> None:
    ack = upload(gcs, 0, _items(0), drop_first_request=True)
    assert ack.type == M.MAV_MISSION_ACCEPTED  # type: ignore[attr-defined]
    # the GCS lost our ACK and sends the last item again: the same ACK, not an error
    f, c, p1, p2, p3, p4, x, y, z = _items(0)[4]
    gcs.send(gcs.mav.mission_item_int_encode(1, 1, 4, f, c, 0, 1, p1, p2, p3, p4, x, y, z, 0))
    assert gcs.recv("MISSION_ACK").type == M.MAV_MISSION_ACCEPTED
    gcs.send(gcs.mav.mission_set_current_encode(1, 1, 3))
    assert gcs.recv("MISSION_CURRENT", 3.0, lambda m: m.seq == 3).total == 5
    assert gcs.command(224, 1, 0).result == M.MAV_RESULT_ACCEPTED  # the command form
    assert gcs.recv("MISSION_CURRENT", 3.0, lambda m: m.seq == 1).total == 5
    assert gcs.command(224, 9, 0).result == M.MAV_RESULT_DENIED
    gcs.send(gcs.mav.mission_clear_all_encode(1, 1, 0))
    assert gcs.recv("MISSION_ACK").type == M.MAV_MISSION_ACCEPTED
    assert idle_rig.ap.mission.download() == ()


def test_refused_mission_gets_an_error_ack_and_reason(gcs: Gcs, idle_rig: Rig) -> None:
    bad = [(REL, 31000, 0, 0, 0, 0, int(LAT0 * 1e7), int(LON0 * 1e7), 5.0)]  # an unknown command
    ack = upload(gcs, 0, bad)
    assert ack.type == M.MAV_MISSION_UNSUPPORTED  # type: ignore[attr-defined]
    assert "31000" in gcs.recv("STATUSTEXT").text
    gcs.send(gcs.mav.mission_request_int_encode(1, 1, 7, 0))
    assert gcs.recv("MISSION_ACK").type == M.MAV_MISSION_INVALID_SEQUENCE


def _ten_items() -> list[tuple[int, int, float, float, float, float, int, int, float]]:
    nan = float("nan")
    d = 4e-5  # about 4.4 m north, 3 m east

    def wp(n: float, e: float, alt: float = 5.0, hold_s: float = 0.0) -> tuple:
        return (
            REL,
            M.MAV_CMD_NAV_WAYPOINT,
            hold_s,
            1.0,
            0,
            nan,
            int((LAT0 + n * d) * 1e7),
            int((LON0 + e * d) * 1e7),
            alt,
        )

    return [
        (REL, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, int(LAT0 * 1e7), int(LON0 * 1e7), 5.0),
        wp(1, 0),
        (M.MAV_FRAME_MISSION, M.MAV_CMD_DO_CHANGE_SPEED, 1, 4.0, -1, 0, 0, 0, 0.0),
        wp(1, 1),
        wp(0, 1, 6.0),
        (M.MAV_FRAME_MISSION, 1000, 0, 0, 0, 0, 0, 0, 0.0),  # gimbal: accepted and stepped over
        wp(0, 0, 6.0, hold_s=1.0),
        (M.MAV_FRAME_MISSION, 2000, 0, 0, 1, 0, 0, 0, 0.0),  # camera: accepted and stepped over
        wp(1, 0),
        (REL, M.MAV_CMD_NAV_LAND, 0, 0, 0, nan, int((LAT0 + d) * 1e7), int(LON0 * 1e7), 0.0),
    ]


def test_ground_station_connect_sequence_then_a_ten_item_mission(gcs: Gcs, flying_rig: Rig) -> None:
    """What QGroundControl does on connect (version, all parameters, mission download), then a 10-item
    mission flown in AUTO.MISSION: every item reached, mission complete, landed, disarmed."""
    assert gcs.command(512, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION).result == M.MAV_RESULT_ACCEPTED
    assert gcs.recv("AUTOPILOT_VERSION").capabilities & M.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    gcs.send(gcs.mav.param_request_list_encode(1, 1))
    params = {m.param_index: m for _, m in gcs.collect(1.0, {"PARAM_VALUE"})}
    assert sorted(params) == list(range(len(flying_rig.ap.params)))
    assert download(gcs, 0) == [] and download(gcs, 1) == [] and download(gcs, 2) == []
    items = _ten_items()
    assert upload(gcs, 0, items).type == M.MAV_MISSION_ACCEPTED  # type: ignore[attr-defined]
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0).result == M.MAV_RESULT_ACCEPTED
    assert gcs.command(M.MAV_CMD_DO_SET_MODE, 1, 4, 4).result == M.MAV_RESULT_ACCEPTED  # AUTO.MISSION
    reached: list[int] = []
    complete = landed = disarmed = False
    deadline = real_monotonic_ns() + 40_000_000_000
    kinds = {"MISSION_ITEM_REACHED", "MISSION_CURRENT", "EXTENDED_SYS_STATE", "HEARTBEAT"}
    while real_monotonic_ns() < deadline and not (complete and landed and disarmed):
        for _, m in gcs.collect(0.1, kinds):
            kind = m.get_type()
            if kind == "MISSION_ITEM_REACHED" and m.seq not in reached:
                reached.append(m.seq)
            elif kind == "MISSION_CURRENT" and m.mission_state == M.MISSION_STATE_COMPLETE:
                complete = True
            elif kind == "EXTENDED_SYS_STATE" and complete:
                landed = m.landed_state == M.MAV_LANDED_STATE_ON_GROUND
            elif kind == "HEARTBEAT" and landed:
                disarmed = not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert reached == list(range(len(items))), "every item reached, in order"
    assert complete and landed and disarmed
    n, e, _ = flying_rig.sim.pos
    assert abs(n - 4e-5 * 111_195) < 1.5 and abs(e) < 1.5, "landed at the last waypoint"


def _upload_one(gcs: Gcs, item: tuple, kind: int = 0, float_form: bool = False) -> object:
    """Upload a mission whose item 1 is ``item`` (item 0: a takeoff); the MISSION_ACK."""
    items = [(REL, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, int(LAT0 * 1e7), int(LON0 * 1e7), 5.0), item]
    gcs.send(gcs.mav.mission_count_encode(1, 1, len(items), kind))
    while True:
        m = gcs.recv(("MISSION_REQUEST_INT", "MISSION_ACK"), 3.0)
        if m.get_type() == "MISSION_ACK":
            return m
        f, c, p1, p2, p3, p4, x, y, z = items[m.seq]
        if float_form and m.seq == 1:
            gcs.send(gcs.mav.mission_item_encode(1, 1, m.seq, f, c, 0, 1, p1, p2, p3, p4, x, y, z, kind))
        else:
            gcs.send(gcs.mav.mission_item_int_encode(1, 1, m.seq, f, c, 0, 1, p1, p2, p3, p4, x, y, z, kind))


@pytest.mark.parametrize(
    ("item", "float_form", "result"),
    [
        ((200, M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, int(LAT0 * 1e7), int((LON0 + 1e-4) * 1e7), 5.0), False, 2),
        ((M.MAV_FRAME_LOCAL_NED, M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, 100_000, 0, -5.0), False, 2),
        ((M.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT, 16, 0, 0, 0, 0, int(LAT0 * 1e7), int(LON0 * 1e7), 5.0), False, 2),
        ((REL, 16, 0, 0, 0, 0, LAT0, LON0, 5.0), True, 2),  # an _INT frame in a float MISSION_ITEM
        ((M.MAV_FRAME_MISSION, M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, 0, 0, 5.0), False, 3),
        ((REL, M.MAV_CMD_DO_CHANGE_SPEED, 1, 3.0, -1, 0, 0, 0, 0.0), False, 3),
        ((REL, M.MAV_CMD_DO_SET_ROI, 7, 0, 0, 0, int(LAT0 * 1e7), int(LON0 * 1e7), 5.0), False, 6),
        ((M.MAV_FRAME_MISSION, M.MAV_CMD_DO_SET_ROI, 3, 0, 0, 0, 0, 0, 0.0), False, 6),
    ],
    ids=["frame-200", "local-ned", "terrain", "int-frame-in-float-item", "waypoint-no-position",
         "speed-with-position", "roi-mode-7", "roi-location-no-position"],
)  # fmt: skip
def test_items_px4_refuses_are_refused_with_px4s_result(
    gcs: Gcs, idle_rig: Rig, item: tuple, float_form: bool, result: int
) -> None:
    """Issue 36, item 2: an item PX4 (``parse_mavlink_mission_item``) refuses is refused with its
    MAV_MISSION_RESULT (UNSUPPORTED_FRAME 2, UNSUPPORTED 3, INVALID_PARAM1 6) and nothing is taken in: a frame of
    200 was accepted and flown as AMSL, into the ground. A STATUSTEXT says why."""
    ack = _upload_one(gcs, item, float_form=float_form)
    assert ack.type == result  # type: ignore[attr-defined]
    assert idle_rig.ap.mission.download() == ()
    assert "mission refused: item 1" in gcs.recv("STATUSTEXT").text
    # the same item in a frame PX4 takes is accepted: the refusal was the frame's
    good = _upload_one(gcs, (REL, M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, int(LAT0 * 1e7), int(LON0 * 1e7), 5.0))
    assert good.type == M.MAV_MISSION_ACCEPTED  # type: ignore[attr-defined]
    assert len(idle_rig.ap.mission.download()) == 2
