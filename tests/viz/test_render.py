"""Offscreen rendering for real (OSMesa on CI machines, EGL with a GPU)."""

import json

import matplotlib.image as mpimg
import numpy as np
import pytest

from cmrt.errors import CmrtError
from cmrt.motion.curve import Cmrt
from cmrt.motion.taskfile import load_task
from cmrt.viz.render import render as render_clip
from tests.service_helpers import FAST_BEND, cmrt


def render(tmp_path, name, *args):
    out = tmp_path / name
    r = cmrt("render", *FAST_BEND, "--frames", "3", "--out", str(out), "--json", *args, check=True)
    return mpimg.imread(out), json.loads(r.stdout)


@pytest.mark.slow  # two software-rendered clips
def test_filmstrip_is_not_blank_and_anticipation_shows(tmp_path):
    zero, zinfo = render(tmp_path, "zero.png", "--curve", "zero")
    lib, linfo = render(tmp_path, "lib.png", "--curve", "library")
    assert zinfo["clips"][0]["success"] is False and linfo["clips"][0]["success"] is True
    for img in (zero, lib):
        assert img.ndim == 3 and img.shape[1] > 300
        assert img[..., :3].std() > 0.05  # not a blank image
    assert zero.shape == lib.shape
    assert np.abs(zero[..., :3] - lib[..., :3]).mean() > 0.01  # the two clips look different


@pytest.mark.slow  # two software-rendered clips
def test_compare_stacks_two_rows(tmp_path):
    both, info = render(tmp_path, "both.png", "--curve", "library", "--compare", "zero")
    single, _ = render(tmp_path, "one.png", "--curve", "library")
    assert [c["success"] for c in info["clips"]] == [False, True]  # top: zero, bottom: library
    assert both.shape[0] > 1.6 * single.shape[0]
    text = cmrt("render", *FAST_BEND, "--frames", "2", "--curve", "library", "--compare", "zero", "--out",
                str(tmp_path / "t.png"), check=True).stdout
    assert "zero CMRT: balance kept, not a success" in text and "library CMRT: SUCCESS" in text  # by verdict


@pytest.mark.slow  # encodes a video
def test_mp4(tmp_path):
    out = tmp_path / "clip.mp4"
    cmrt("render", *FAST_BEND, "--fps", "5", "--out", str(out), check=True)
    assert out.stat().st_size > 5_000


@pytest.mark.slow  # a cmrt process
def test_bad_output_name(tmp_path):
    r = cmrt("render", *FAST_BEND, "--out", str(tmp_path / "clip.gif"))
    assert r.returncode == 2 and ".png or .mp4" in r.stderr


def test_bad_output_name_in_process(tmp_path):
    """The same refusal by ``cmrt.viz.render.render`` in this process, before anything is simulated or drawn."""
    with pytest.raises(CmrtError, match=r"\.png or \.mp4"):
        render_clip(load_task("bend").with_speed(0.4), Cmrt.zero(2.6), tmp_path / "clip.gif")
