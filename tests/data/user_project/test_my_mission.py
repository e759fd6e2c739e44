"""The user's mission test: uav-harness's pytest plugin flies it on the sim clock and the test asserts on the flight."""

from pathlib import Path

HERE = Path(__file__).parent


def test_my_mission_climbs_to_5_m_and_lands_where_it_took_off(harness_run):
    run = harness_run(mission=HERE / "my_mission.py", vehicles=1, duration_s=120, seed=1)
    assert run.ok, run.message
    vehicle = run.vehicle(0)
    assert "landed" in run.mission_output(0)
    assert 4.5 < vehicle.max_altitude_m < 5.5
    assert vehicle.landed and not vehicle.crashed
    assert vehicle.distance_from_start_m() < 1.0
