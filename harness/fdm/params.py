"""The quad-X airframe: every parameter of ``models/aircraft/quadx/quadx.xml`` with its unit and source.

The vehicle is the 450-class quadrotor PX4's Gazebo SITL flies as "iris" (3DR Iris): the values for mass,
inertia, thrust and yaw-moment constants come from PX4's ``iris.sdf`` model (PX4-SITL_gazebo-classic),
the rest are stated estimates for a 450 frame. ``tests/fdm/test_model.py`` loads the XML into JSBSim
and checks it agrees with this file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

G_M_S2 = 9.80665
LBF_PER_N = 0.2248089431
N_PER_LBF = 1.0 / LBF_PER_N
M_PER_FT = 0.3048
FT_PER_M = 1.0 / M_PER_FT
KG_PER_SLUG = 14.59390294


@dataclass(frozen=True)
class QuadParams:
    mass_kg: float = 1.5
    """Take-off mass. Source: iris.sdf base_link mass 1.5 kg."""
    ixx_kg_m2: float = 0.029125
    """Roll inertia. Source: iris.sdf."""
    iyy_kg_m2: float = 0.029125
    """Pitch inertia. Source: iris.sdf."""
    izz_kg_m2: float = 0.055225
    """Yaw inertia. Source: iris.sdf."""
    arm_m: float = 0.25
    """Centre-to-rotor distance (450 mm motor-to-motor diagonal /2 ≈ 0.225–0.25 m); rotors at 45°."""
    thrust_max_n: float = 7.07
    """Thrust of one rotor at full command. Source: iris.sdf motorConstant 5.84e-6 N/(rad/s)² ×
    maxRotVelocity² (1100 rad/s)² = 7.07 N; thrust-to-weight 1.92."""
    yaw_moment_per_thrust_m: float = 0.06
    """Rotor drag torque per newton of thrust. Source: iris.sdf momentConstant 0.06 m."""
    motor_time_constant_s: float = 0.02
    """First-order lag from command to rotor thrust. iris.sdf: 0.0125 s up, 0.025 s down; one lag of
    0.02 s here (JSBSim lag_filter c1 = 50 /s)."""
    body_cda_m2: float = 0.04
    """Quadratic body drag area Cd·A (frame, battery, arms seen from any side), estimate for a 450 frame."""
    rotor_drag_n_per_m_s: float = 0.35
    """Linear rotor (induced) drag per m/s of airspeed, horizontal and vertical; the dominant drag of a
    small multirotor below ~8 m/s (estimate after the rotor-drag literature for 10-inch props)."""
    skid_below_cg_m: float = 0.10
    """Height of the centre of gravity above the landing skids."""

    @property
    def weight_n(self) -> float:
        return self.mass_kg * G_M_S2

    @property
    def hover_command(self) -> float:
        """Normalised command at which the four rotors carry the weight: thrust = T_max · u²."""
        return math.sqrt(self.weight_n / (4.0 * self.thrust_max_n))

    @property
    def rotor_positions_m(self) -> tuple[tuple[float, float], ...]:
        """(x forward, y right) of rotors 0..3 in PX4 quad-X order: front-right, rear-left, front-left,
        rear-right."""
        a = self.arm_m / math.sqrt(2.0)
        return ((a, a), (-a, -a), (a, -a), (-a, a))

    @property
    def rotor_spin(self) -> tuple[int, ...]:
        """+1 counter-clockwise seen from above (rotors 0 and 1), −1 clockwise. A CCW rotor pushes the
        body clockwise: positive yaw about body z (down), as PX4's mixer expects (yaw coefficient +1)."""
        return (1, 1, -1, -1)


DEFAULT_QUAD = QuadParams()


def models_root() -> Path:
    """JSBSim root directory holding ``aircraft/quadx/quadx.xml`` (package data)."""
    return Path(str(resources.files("harness.fdm") / "models"))
