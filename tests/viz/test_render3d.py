"""Filmstrips of a 3D clip (cmrt.viz.render3d): a front row over a side row, captioned; the body in frame."""

import numpy as np
import pytest
from PIL import Image

from cmrt.errors import CmrtError
from cmrt.sim.spatial import stand_3d
from cmrt.viz import overlay
from cmrt.viz.render3d import VIEWS, filmstrip_3d


@pytest.fixture(scope="module")
def pushed():
    return stand_3d(clip_s=1.5, push_n=(0.0, 100.0, 0.0), push_start_s=0.5)


@pytest.mark.slow  # renders
def test_a_front_row_over_a_side_row(pushed, tmp_path):
    out = tmp_path / "strip.png"
    written = filmstrip_3d(pushed, np.array([0.2, 0.8]), out, height=160, width=120)
    assert written["views"] == [v for v, _ in VIEWS] and written["times_s"] == [0.2, 0.8]
    img = np.asarray(Image.open(out).convert("RGB"))
    assert img.shape == (2 * (160 + overlay.CAPTION_PX), 2 * 120, 3)
    for r in range(2):  # every frame shows the body: pixels that are neither sky nor floor change between views
        frame = img[r * (160 + overlay.CAPTION_PX) + overlay.CAPTION_PX:(r + 1) * (160 + overlay.CAPTION_PX), :120]
        assert frame.std() > 10


def test_a_bad_output_is_refused_before_rendering(pushed, tmp_path):
    with pytest.raises(CmrtError, match="--filmstrip"):
        filmstrip_3d(pushed, np.array([0.2]), tmp_path / "strip.gif")
