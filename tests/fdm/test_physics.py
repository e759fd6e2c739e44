"""Acceptance of the FDM (issue 3): JSBSim physics against closed form, determinism, bad input."""

from __future__ import annotations

import math

import jsbsim
import pytest

from harness.core.errors import ScenarioError, SimulationError
from harness.fdm.environment import WindConfig
from harness.fdm.params import DEFAULT_QUAD, G_M_S2, KG_PER_SLUG, models_root
from harness.fdm.physics import Physics, PhysicsConfig
from harness.fdm.sensors import SensorConfig

QUIET = SensorConfig(noise=False)


def figure(name: str, **values: float) -> None:
    print("FIGURE", name, " ".join(f"{k}={v:.6g}" for k, v in values.items()))


def test_model_file_agrees_with_documented_parameters() -> None:
    fdm = jsbsim.FGFDMExec(str(models_root()), None)
    fdm.load_model("quadx")
    fdm["ic/h-agl-ft"] = 100.0
    fdm.run_ic()
    assert fdm["inertia/mass-slugs"] * KG_PER_SLUG == pytest.approx(DEFAULT_QUAD.mass_kg, rel=1e-4)
    slug_ft2 = KG_PER_SLUG * 0.3048**2
    assert fdm["inertia/ixx-slugs_ft2"] * slug_ft2 == pytest.approx(DEFAULT_QUAD.ixx_kg_m2, rel=1e-4)
    assert fdm["inertia/izz-slugs_ft2"] * slug_ft2 == pytest.approx(DEFAULT_QUAD.izz_kg_m2, rel=1e-4)


def test_free_fall_from_100_m_lands_at_the_closed_form_time() -> None:
    ph = Physics(PhysicsConfig(drag=False, sensors=QUIET, spawn_ned_m=((0.0, 0.0, -100.0),), crash_speed_m_s=1e9))
    h = -ph.frames()[0].truth.pos_ned_m[2] - DEFAULT_QUAD.skid_below_cg_m  # skid height above ground
    while not ph.frames()[0].truth.on_ground:
        ph.step([(0.0, 0.0, 0.0, 0.0)])
    t = ph.t_ns / 1e9
    expected = math.sqrt(2 * h / G_M_S2)
    figure("free_fall", t_s=t, expected_s=expected, error_pct=100 * (t - expected) / expected)
    assert t == pytest.approx(expected, rel=0.01)


def test_thrust_equals_weight_at_the_documented_hover_command() -> None:
    ph = Physics(PhysicsConfig(drag=False, sensors=QUIET, spawn_ned_m=((0.0, 0.0, -50.0),)))
    u = DEFAULT_QUAD.hover_command
    for _ in range(250):  # 1 s: the motor lag has settled
        f = ph.step([(u, u, u, u)])[0]
    specific_force_z = f.imu.accel_body_m_s2[2]
    thrust = -specific_force_z * DEFAULT_QUAD.mass_kg
    figure("hover", command=u, thrust_n=thrust, weight_n=DEFAULT_QUAD.weight_n)
    assert thrust == pytest.approx(DEFAULT_QUAD.weight_n, rel=0.02)
    assert abs(f.truth.vel_ned_m_s[2]) < 0.05


def test_differential_thrust_gives_tau_over_j() -> None:
    ph = Physics(PhysicsConfig(drag=False, sensors=QUIET, spawn_ned_m=((0.0, 0.0, -50.0),)))
    u, du = DEFAULT_QUAD.hover_command, 0.05
    for _ in range(250):
        ph.step([(u, u, u, u)])
    p0 = ph.frames()[0].truth.rates_body_rad_s[0]
    # left rotors (1 rear-left, 2 front-left) up, right rotors down: a pure positive roll torque
    cmd = (u - du, u + du, u + du, u - du)
    for _ in range(50):  # 0.2 s: 10 motor time constants
        ph.step([cmd])
    f0 = ph.frames()[0].truth.rates_body_rad_s[0]
    ph.step([cmd])
    f1 = ph.frames()[0].truth.rates_body_rad_s[0]
    alpha = (f1 - f0) / 0.004
    t_hi, t_lo = DEFAULT_QUAD.thrust_max_n * (u + du) ** 2, DEFAULT_QUAD.thrust_max_n * (u - du) ** 2
    y = DEFAULT_QUAD.arm_m / math.sqrt(2)
    tau = 2 * (t_hi - t_lo) * y
    expected = tau / DEFAULT_QUAD.ixx_kg_m2
    figure("roll_accel", measured_rad_s2=alpha, expected_rad_s2=expected)
    assert p0 == pytest.approx(0.0, abs=1e-6)
    assert alpha == pytest.approx(expected, rel=0.05)


def test_yaw_reaction_has_the_sign_px4_expects() -> None:
    ph = Physics(PhysicsConfig(drag=False, sensors=QUIET, spawn_ned_m=((0.0, 0.0, -50.0),)))
    u, du = DEFAULT_QUAD.hover_command, 0.05
    for _ in range(125):  # CCW rotors 0 and 1 faster: PX4's positive yaw (nose right)
        f = ph.step([(u + du, u + du, u - du, u - du)])[0]
    r = f.truth.rates_body_rad_s[2]
    figure("yaw", r_rad_s=r)
    assert r > 0.1


def test_wind_at_hover_thrust_drifts_downwind() -> None:
    ph = Physics(
        PhysicsConfig(sensors=QUIET, spawn_ned_m=((0.0, 0.0, -50.0),), wind=WindConfig(steady_ned_m_s=(0.0, 5.0, 0.0)))
    )
    u = DEFAULT_QUAD.hover_command
    for _ in range(250 * 5):
        f = ph.step([(u, u, u, u)])[0]
    n, e, _ = f.truth.pos_ned_m
    figure("wind_drift", east_m=e, north_m=n, ve_m_s=f.truth.vel_ned_m_s[1])
    assert e > 2.0 and abs(n) < 0.5 * e  # blown east, the way the wind goes
    assert 0 < f.truth.vel_ned_m_s[1] <= 5.0


@pytest.mark.parametrize(("wind_m_s", "limit_m"), [(0.0, 1e-6), (3.0, 0.02)])
def test_at_rest_on_the_ground_it_does_not_drift(wind_m_s: float, limit_m: float) -> None:
    """Still air: no drift at all. In wind, JSBSim's contact friction lets the skids creep (1.6 cm/min
    at 3 m/s, documented in docs/fdm.md); the bound pins that figure down."""
    ph = Physics(PhysicsConfig(sensors=QUIET, wind=WindConfig(steady_ned_m_s=(wind_m_s, 0.0, 0.0))))
    for _ in range(250):  # the skids settle on their springs in the first second
        ph.step([(0.0,) * 4])
    start = ph.frames()[0].truth.pos_ned_m
    for _ in range(250 * 60):
        f = ph.step([(0.0,) * 4])[0]
    end = f.truth.pos_ned_m
    horizontal = math.hypot(end[0] - start[0], end[1] - start[1])
    figure("ground_drift_60s", horizontal_m=horizontal, vertical_m=end[2] - start[2])
    assert horizontal < limit_m and abs(end[2] - start[2]) < 1e-3
    assert f.truth.on_ground and not f.truth.crashed


def test_same_seed_gives_bit_identical_streams() -> None:
    def run(seed: int) -> list[object]:
        ph = Physics(PhysicsConfig(n_vehicles=2, seed=seed, wind=WindConfig((2.0, 1.0, 0.0), turbulence="light")))
        out: list[object] = []
        u = DEFAULT_QUAD.hover_command * 1.02
        for _ in range(500):
            out.extend(ph.step([(u, u, u, u)] * 2))
        return out

    a, b, c = run(7), run(7), run(8)
    assert a == b
    assert a != c


def test_a_share_of_the_vehicles_is_bit_identical_to_the_same_vehicles_of_the_whole() -> None:
    """A worker builds ``Physics(config, its vehicles)`` from the run's configuration (sent as JSON): each of
    its vehicles must be the very vehicle the whole run would have (spawn point, sensor and turbulence
    streams from its own share of the seed), whichever others are simulated beside it."""
    cfg = PhysicsConfig(
        n_vehicles=4,
        seed=11,
        wind=WindConfig((2.0, -1.0, 0.0), turbulence="moderate"),
        spawn_ned_m=((0.0, 0.0, 0.0), (3.0, 1.0, 0.0), (-2.0, 4.0, -1.0), (7.0, 7.0, 0.0)),
        sensors=SensorConfig.for_gps("standalone"),
    )
    sent = PhysicsConfig.from_json(cfg.to_json())
    assert sent == cfg
    whole, share = Physics(cfg), Physics(sent, [3, 1])
    assert share.owned == (3, 1) and [f.vehicle for f in share.frames()] == [3, 1]
    u = DEFAULT_QUAD.hover_command * 1.05
    cmds = {1: (u, u, u, u), 3: (u * 0.99, u, u * 1.01, u)}
    for _ in range(300):
        frames = {f.vehicle: f for f in whole.step([cmds.get(i, (0.0,) * 4) for i in range(4)])}
        mine = share.step([cmds[3], cmds[1]])
        assert mine == [frames[3], frames[1]]
    assert -mine[1].truth.pos_ned_m[2] > 0.1  # it flew, in the gusts
    with pytest.raises(ScenarioError, match="not distinct indices below 4"):
        Physics(cfg, [1, 4])
    with pytest.raises(ScenarioError, match="not a physics configuration"):
        PhysicsConfig.from_json(b'{"n_vehicles": "two"}')


def test_bad_commands_are_clamped_and_counted() -> None:
    ph = Physics(PhysicsConfig(sensors=QUIET))
    ph.step([(math.nan, math.inf, -math.inf, 1.5)])
    assert ph.vehicles[0].motors == (0.0, 1.0, 0.0, 1.0)
    c = ph.counters(0)
    assert c.clamped_commands == 4 and c.nan_commands == 1
    for x in (ph.vehicles[0].fdm[f"fcs/motor-cmd[{i}]"] for i in range(4)):
        assert math.isfinite(x) and 0.0 <= x <= 1.0


def test_malformed_commands_are_refused_with_a_clear_error() -> None:
    ph = Physics(PhysicsConfig(n_vehicles=2, sensors=QUIET))
    with pytest.raises(SimulationError, match="vehicle 0 got 3 motor commands"):
        ph.step([(0.1, 0.2, 0.3), (0.0,) * 4])
    with pytest.raises(SimulationError, match="for 1 vehicles, simulating 2"):
        ph.step([(0.0,) * 4])


def test_hard_impact_is_a_crash_and_cuts_the_motors() -> None:
    ph = Physics(PhysicsConfig(sensors=QUIET, spawn_ned_m=((0.0, 0.0, -5.0),)))
    u = DEFAULT_QUAD.hover_command
    while not ph.frames()[0].truth.on_ground:
        ph.step([(0.0,) * 4])
    f = ph.step([(u, u, u, u)])[0]
    assert f.truth.crashed and ph.crashed(0)
    assert ph.vehicles[0].motors == (0.0, 0.0, 0.0, 0.0)
    assert ph.vehicles[0].impact_speed_m_s > 3.0


def test_a_vehicle_spawned_on_the_ground_stands_on_it_from_the_first_frame() -> None:
    ph = Physics(PhysicsConfig(n_vehicles=2, sensors=QUIET, spawn_ned_m=((0.0, 0.0, 0.0), (5.0, 0.0, -20.0))))
    ground, air = ph.frames()  # before any step: JSBSim has not computed a gear force yet
    assert ground.truth.on_ground and not air.truth.on_ground
    for _ in range(5):
        ground, air = ph.step([(0.0,) * 4, (0.0,) * 4])
    assert ground.truth.on_ground and not air.truth.on_ground and not ground.truth.crashed
