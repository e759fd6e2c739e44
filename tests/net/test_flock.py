"""Acceptance (issue 6): five vehicles flock over the built-in radio for 120 s of sim time; with the network
dropping everything, the same flock measurably falls apart."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.net.flocking import flock_figures, fly_scenario

pytestmark = pytest.mark.sim
FLOCK = Path(__file__).resolve().parents[2] / "missions" / "flock.py"


def fly(tmp_path: Path, name: str, max_range_m: float) -> tuple[float, float]:
    out = fly_scenario(
        f'[vehicles]\ncount = 5\nmission = "{FLOCK}"\nargs = ["120"]\n'
        f'[network]\nmodel = "builtin"\nparams = {{ max_range_m = {max_range_m} }}\n',
        tmp_path / name,
    )
    f = flock_figures(out, 5)
    print(
        f"FIGURE flock {name}: {f.flocking_s:.0f} s, min separation {f.min_separation_m:.2f} m, "
        f"max from centroid {f.max_from_centroid_m:.2f} m"
    )
    assert f.flocking_s >= 120.0
    return f.min_separation_m, f.max_from_centroid_m


def test_flock_holds_over_the_radio_and_falls_apart_without_it(tmp_path: Path) -> None:
    sep, spread = fly(tmp_path, "radio", 2000.0)
    assert sep > 2.0 and spread < 30.0
    sep_off, spread_off = fly(tmp_path, "silent", 0.5)
    assert spread_off > 2 * spread and sep_off < sep  # measurably worse on both
