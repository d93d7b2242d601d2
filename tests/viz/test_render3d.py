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


@pytest.mark.slow  # renders
def test_a_prop_in_front_of_the_body_is_seen_past_from_behind(tmp_path):
    """The heavy bag hangs in front of the 3D body and hides its trunk from the front view: a task with a prop in
    front (a bag, a slab) is drawn from behind instead. Measured with MuJoCo's segmentation rendering from the
    render's own camera: the pixels of the trunk's and head's geoms, from behind and from the front."""
    import mujoco

    from cmrt.body.character import character
    from cmrt.motion.curve import Cmrt
    from cmrt.motion.taskfile import load_task
    from cmrt.sim.spatial import stand_pose_qpos
    from cmrt.viz.render import _renderer
    from cmrt.viz.render3d import BEHIND, DISTANCE_M, ELEVATION_DEG, PROPS_IN_FRONT, render_3d

    task = load_task("punch3d")
    assert task.prop in PROPS_IN_FRONT and load_task("catch3d").prop not in PROPS_IN_FRONT
    model, body = task.model(), character(task.body).model
    d = mujoco.MjData(model)
    d.qpos[:body.nq] = stand_pose_qpos(task.start_pose_deg)  # the prop's coordinates at their defaults
    mujoco.mj_forward(model, d)
    upper = {mujoco.mj_name2id(body, mujoco.mjtObj.mjOBJ_BODY, n) for n in ("thorax", "head")}
    trunk = [g for g in range(body.ngeom) if body.geom_bodyid[g] in upper]
    renderer = _renderer(model, 160, 120)  # the render's own (its GL set up as `cmrt render` sets it)
    renderer.enable_segmentation_rendering()
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = (d.subtree_com[1, 0], d.subtree_com[1, 1], 0.7)
    camera.distance, camera.elevation = DISTANCE_M, ELEVATION_DEG
    seen = {}
    for name, azimuth in (VIEWS[0], BEHIND[0]):
        camera.azimuth = azimuth
        renderer.update_scene(d, camera)
        seg = renderer.render()
        seen[name] = int(np.isin(seg[..., 0], trunk)[seg[..., 1] == mujoco.mjtObj.mjOBJ_GEOM].sum())
    renderer.close()
    assert seen["back"] > 200 and seen["back"] > 5 * seen["front"], seen
    written = render_3d(task.with_params(clip_s=1.5), Cmrt.zero(1.5, 2), tmp_path / "p.png", n_frames=2,
                        height=80, width=60)
    assert written["views"] == [v for v, _ in BEHIND]
