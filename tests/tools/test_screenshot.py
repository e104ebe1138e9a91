"""The viewer as a user sees it: a run shown by the native rerun viewer under Xvfb, captured
by `python -m pipeline.tools.screenshot` and looked at (slow: ~20 s of software rendering)."""

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pipeline.tools.screenshot import MARK
from pipeline.tools.viewer import DEMO, FINAL_PATHS, LINK, TAB10
from tests.conftest import ROOT, run_in_process

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(shutil.which("Xvfb") is None, reason="Xvfb is not installed, so the "
                       "viewer cannot be rendered headless: apt-get install xvfb imagemagick "
                       "mesa-vulkan-drivers"),
]


def pixels_of(image: np.ndarray, colour, tol: int = 8) -> int:
    """How many pixels have this colour (each channel within tol)."""
    return int((np.abs(image.astype(int) - np.array(colour)).max(axis=-1) <= tol).sum())


def processes_marked(value: str) -> list[int]:
    """Pids of the processes whose environment holds MARK=value (Linux /proc)."""
    needle = f"{MARK}={value}".encode()
    pids = []
    for environ in Path("/proc").glob("[0-9]*/environ"):
        try:
            if needle in environ.read_bytes().split(b"\0"):
                pids.append(int(environ.parent.name))
        except OSError:  # gone meanwhile, or not ours to read
            pass
    return pids


def test_the_viewer_draws_the_scene_and_the_curves(tmp_path):
    run_dir = tmp_path / "run"
    run_in_process(run_dir, "graph=small", "birl.n_iterations=4")
    out = tmp_path / "shot.png"
    res = subprocess.run([sys.executable, "-m", "pipeline.tools.screenshot", str(run_dir),
                          "--out", str(out)], cwd=ROOT, capture_output=True, text=True,
                         timeout=300, check=False)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == f"wrote {out}"
    assert not processes_marked(str(run_dir / "run.rrd")), "Xvfb or the viewer still runs"
    with Image.open(out) as png:
        assert png.size == (1600, 1000)
        image = np.asarray(png.convert("RGB"))
    # A blank (black) capture has one colour; the viewer's panels, text and plots thousands.
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 1000
    # The recording is on screen, not only the viewer's frame: the social links and the
    # final learned paths in the scene view; the policy-loss and weight curves (tab10's first
    # colours) and the log posterior (its fifth) in the plots.
    assert pixels_of(image, LINK) > 500 and pixels_of(image, FINAL_PATHS) > 500
    # the demonstrations, drawn above the learned paths they mostly run along, show
    assert pixels_of(image, DEMO) > 500
    for colour in (TAB10[0], TAB10[1], TAB10[2], TAB10[4]):
        assert pixels_of(image, colour) > 50, colour
