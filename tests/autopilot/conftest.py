"""Fixtures for the acceptance tests: the real FDM (JSBSim) with sensor noise on."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest


def _physics(**kw: Any) -> Callable[..., Any]:
    mod = pytest.importorskip("harness.fdm.physics")

    def make(seed: int = 0) -> Any:
        return mod.Physics(mod.PhysicsConfig(n_vehicles=1, seed=seed, substep_hz=1000, tick_hz=250, **kw))

    return make


@pytest.fixture
def fdm() -> Callable[..., Any]:
    return _physics()


@pytest.fixture
def fdm_wind() -> Callable[..., Any]:
    mod = pytest.importorskip("harness.fdm.physics")
    return _physics(wind=mod.WindConfig(steady_ned_m_s=(5.0, 0.0, 0.0), turbulence="light"))


@pytest.fixture
def fdm_standalone_gps() -> Callable[..., Any]:
    """A single receiver's GPS error (σ 0.3 m, wandering over 20 s) instead of the PX4-SITL default."""
    mod = pytest.importorskip("harness.fdm.sensors")
    return _physics(sensors=mod.SensorConfig.for_gps("standalone"))


@pytest.fixture
def fdm_white_gps() -> Callable[..., Any]:
    """The standalone error level (σ 0.3 m) decorrelating within 0.1 s."""
    mod = pytest.importorskip("harness.fdm.sensors")
    return _physics(sensors=mod.SensorConfig.for_gps("standalone", gps_error_tau_s=0.1))


@pytest.fixture
def fdm_no_gps() -> Callable[..., Any]:
    mod = pytest.importorskip("harness.fdm.physics")
    return _physics(sensors=mod.SensorConfig(gps_fix_type=1))
