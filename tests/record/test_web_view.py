"""Acceptance (issue 15): a real headless Chromium opens the ``--view web`` URL during a 3-vehicle run and
shows the vehicles — asserted on the pixels of their colours in the 3D view's part of the screenshot."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from harness.record.scene import vehicle_color
from harness.record.sink import rerun_available
from tests.record.browser import chromium, find_chromium, open_page

pytestmark = pytest.mark.sim
ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "missions" / "swarm_demo.py"


def _need(what: str, ok: bool, how: str) -> None:
    if ok:
        return
    if os.environ.get("CI") == "true":
        pytest.fail(f"{what} is missing in CI ({how}); this test must not be skipped there")
    pytest.skip(f"{what} is not installed ({how})")


def colour_pixels(png: Path, color: tuple[int, int, int], box: tuple[float, float, float, float]) -> int:
    """Pixels within a small distance of ``color`` inside ``box`` (fractions of width and height)."""
    import numpy as np
    from PIL import Image

    img = np.asarray(Image.open(png).convert("RGB"), dtype=np.int32)
    h, w, _ = img.shape
    x0, y0, x1, y1 = box
    part = img[int(y0 * h) : int(y1 * h), int(x0 * w) : int(x1 * w)]
    dist = np.abs(part - np.asarray(color)).sum(axis=2)
    return int((dist < 60).sum())


RUN_ARGS = ("--network", "builtin", "--speed", "1", "--duration", "150", "--view", "web", "--out")
SCENE_BOX = (0.0, 0.07, 0.58, 0.78)
"""The 3D view in the blueprint's layout (left 3/5, above the events), without the series and their legends."""


def test_headless_chromium_shows_the_swarm_in_the_web_viewer(tmp_path: Path) -> None:
    _need("Rerun (the view extra)", rerun_available(), "pip install 'uav-harness[view]'; dev.py test installs it")
    _need("chromium", find_chromium() is not None, "apt-get install chromium; dev.py test installs it")
    out = tmp_path / "run"
    env = dict(os.environ, XDG_CONFIG_HOME=str(tmp_path / "xdg"))
    run = subprocess.Popen(
        [sys.executable, "-m", "harness.cli", "run", "--vehicles", "3", "--mission", str(DEMO), *RUN_ARGS, str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=env,
        start_new_session=True,
    )
    try:
        assert run.stdout is not None
        url = None
        for line in run.stdout:  # the first line: the URL
            m = re.search(r"3D view \(web viewer\): (http://\S+)", line)
            if m:
                url = m.group(1)
                break
        assert url, "harness run --view web printed no URL"
        shot = out / "web-view.png"
        counts: list[int] = []
        t0 = time.monotonic()
        with chromium(tmp_path / "chromium") as (_proc, port):
            page = open_page(port, url)
            # the wasm compiles for 10-15 s (more on a loaded machine); then the vehicles stream in
            while time.monotonic() - t0 < 150 and run.poll() is None:
                time.sleep(3)
                page.screenshot(shot)
                counts = [colour_pixels(shot, vehicle_color(i), SCENE_BOX) for i in range(3)]
                if min(counts) >= 40:
                    time.sleep(5)  # a little flight on screen for the picture
                    page.screenshot(shot)
                    counts = [colour_pixels(shot, vehicle_color(i), SCENE_BOX) for i in range(3)]
                    break
            page.close()
        print(f"FIGURE web view: vehicle colour pixels {counts} after {time.monotonic() - t0:.0f} s; {shot}")
        from PIL import Image

        colours = Image.open(shot).convert("RGB").getcolors(1_000_000) or []
        assert len(colours) > 200, "the screenshot is blank"
        assert min(counts) >= 40, f"the vehicles' colours are not in the 3D view: {counts} pixels (see {shot})"
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGINT)
        code = run.wait(60)
    assert code in (0, 130), f"harness run ended with {code}"
    assert (out / "summary.json").is_file() and (out / "world.rrd").is_file()
