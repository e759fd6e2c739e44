"""The IMU model's per-tick arithmetic, compiled with numba (``harness.core.jit``).

``SensorModel`` (``sensors.py``) imports this module when a vehicle's sensors are made, so the scenario
layer and the sweep driver, which read ``SensorConfig``, do not import numba.
"""

from __future__ import annotations

from harness.core.jit import Floats, compiled, kernel


@kernel
def imu_sample(
    z: Floats,
    at: int,
    s: Floats,
    c: Floats,
    sf0: float,
    sf1: float,
    sf2: float,
    w0: float,
    w1: float,
    w2: float,
) -> tuple[float, float, float, float, float, float]:
    """One IMU sample: the biases in ``s`` (accelerometer 3, gyro 3, barometer) take a random-walk step and
    the readings get them plus white noise. ``z[at:at + 12]``: the IMU's standard normal draws, ``z[at + 12]``
    the barometer drift's; ``c``: walk per tick (accelerometer, gyro), noise σ (accelerometer, gyro), baro walk.
    Returns (specific force (3), rates (3)) in body axes."""
    wa, wg, an, gn = c[0], c[1], c[2], c[3]
    ab0 = s[0] = s[0] + wa * z[at]
    gb0 = s[3] = s[3] + wg * z[at + 3]
    ab1 = s[1] = s[1] + wa * z[at + 1]
    gb1 = s[4] = s[4] + wg * z[at + 4]
    ab2 = s[2] = s[2] + wa * z[at + 2]
    gb2 = s[5] = s[5] + wg * z[at + 5]
    s[6] += c[4] * z[at + 12]
    return (
        sf0 + ab0 + an * z[at + 6],
        sf1 + ab1 + an * z[at + 7],
        sf2 + ab2 + an * z[at + 8],
        w0 + gb0 + gn * z[at + 9],
        w1 + gb1 + gn * z[at + 10],
        w2 + gb2 + gn * z[at + 11],
    )


imu_sample_entry = compiled(imu_sample)
"""``imu_sample``'s compiled entry point (``jit.compiled``), for ``SensorModel.sample``."""
