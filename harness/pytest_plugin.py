"""pytest plugin of uav-harness (entry point ``pytest11``): markers for simulation tests."""

from __future__ import annotations

import pytest


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "sim: a test that flies a real simulation (physics, autopilot, missions)")
    config.addinivalue_line("markers", "soak: a long-running soak test; CI runs it at a small size")
