"""Offscreen rendering for real (OSMesa on CI machines, EGL with a GPU)."""

import json

import matplotlib.image as mpimg
import numpy as np
import pytest

from cmrt.errors import CmrtError
from cmrt.motion.curve import Cmrt
from cmrt.motion.taskfile import load_task
from cmrt.sim.objective import evaluate
from cmrt.sim.simulate import simulate
from cmrt.viz import overlay
from cmrt.viz import render as rr
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
    assert "zero CMRT: balance kept, not a success: on time" in text and "library CMRT: SUCCESS" in text  # by verdict


@pytest.mark.slow  # encodes a video
def test_mp4(tmp_path):
    out = tmp_path / "clip.mp4"
    cmrt("render", *FAST_BEND, "--fps", "5", "--curve", "library", "--compare", "zero", "--out", str(out),
         check=True)
    assert out.stat().st_size > 5_000
    import imageio.v2 as imageio

    frames = imageio.mimread(out, format="FFMPEG")
    assert len(frames) == 16  # 0 to 3.1 s at 5 frames a second
    first = frames[0].astype(int)
    assert first.shape[1] == 2 * 240 and first.shape[0] > 320 + overlay.CAPTION_PX  # side by side, key under them
    band = first[:overlay.CAPTION_PX]
    assert (band.sum(-1) > 600).sum() > 200  # the captions' white text, through the codec's blur
    green = np.abs(band[:, 240:] - overlay.GREEN).sum(-1) < 60  # "SUCCESS" over the library clip, not the zero one
    assert green.sum() > 20 and (np.abs(band[:, :240] - overlay.GREEN).sum(-1) < 60).sum() < green.sum() / 4


@pytest.mark.slow  # a cmrt process
def test_bad_output_name(tmp_path):
    r = cmrt("render", *FAST_BEND, "--out", str(tmp_path / "clip.gif"))
    assert r.returncode == 2 and ".png or .mp4" in r.stderr


def test_bad_output_name_in_process(tmp_path):
    """The same refusal by ``cmrt.viz.render.render`` in this process, before anything is simulated or drawn."""
    with pytest.raises(CmrtError, match=r"\.png or \.mp4"):
        render_clip(load_task("bend").with_speed(0.4), Cmrt.zero(2.6), tmp_path / "clip.gif")


# --- what a researcher reads off a picture (issue 29 item 7) ---------------------------------------------------

FAST_BEND_END_S = 3.098  # the fast bend's clip and standing tail (the last recorded step)


def test_fast_bend_filmstrip_crowds_into_the_motion_window():
    """The fast bend's 0.4 s motion gets most of the 8 frames (evenly spaced from 0.8 s, one fell in it)."""
    task = load_task("bend").with_speed(0.4)
    window = rr.motion_window(task)
    assert window == (1.0, 1.4)
    times = rr.filmstrip_times(window, [], FAST_BEND_END_S, 8)
    inside = times[(times >= 1.0) & (times <= 1.4)]
    assert inside.size >= 3
    assert np.diff(inside).max() <= 0.15  # spread over the motion, not bunched at one end
    assert times[0] == pytest.approx(0.8) and times[-1] == pytest.approx(3.1)  # the pose before, the end
    uniform = np.linspace(0.8, FAST_BEND_END_S, 8)
    assert ((uniform >= 1.0) & (uniform <= 1.4)).sum() == 1  # what the evenly spaced strip showed
    assert 1.0 <= rr.filmstrip_times(window, [], FAST_BEND_END_S, 3)[1] <= 1.4  # three frames: one in the motion


@pytest.mark.parametrize("n", [3, 8, 20])
def test_a_falling_clips_frames_include_the_fall(n):
    times = rr.filmstrip_times((1.0, 1.4), [2.064], FAST_BEND_END_S, n)
    assert times.size == n and 2.064 in times
    if n >= 8:  # a frame before the fall and one after it, besides the last
        assert ((times > 1.8) & (times < 2.064)).any() and ((times > 2.064) & (times < 2.5)).any()
        assert (((times >= 1.0) & (times <= 1.4)).sum()) >= 3  # the motion keeps its frames
    both = rr.filmstrip_times((1.0, 1.4), [1.5, 2.064], FAST_BEND_END_S, n)  # two clips falling apart
    assert {1.5, 2.064} <= set(both.tolist())


def test_a_push_tasks_window_is_its_pushes_and_the_reaction():
    lo, hi = rr.motion_window(load_task("push-recovery"))
    assert lo == pytest.approx(1.0) and hi > lo + 0.5
    assert rr.motion_window(load_task("stand")) == (0.0, 10.0)  # nothing happens: the whole clip


def test_lookat_stays_home_then_follows_the_com_and_keeps_the_body_in_view():
    home, half = rr.CAMERA_HOME_M[0], 1.0
    assert rr.lookat_x(home + 0.1, -0.3, 0.4, half) == home  # standing sway: the camera holds still
    assert rr.lookat_x(home + 0.6, 0.3, 0.9, half) == pytest.approx(home + 0.6 - rr.FOLLOW_DEADZONE_M)
    x = rr.lookat_x(home + 0.2, -0.2, 1.8, 1.2)  # lying along +x: its head would leave the picture
    assert x > home + 0.2 and 1.8 + rr.VIEW_MARGIN_M <= x + 1.2 + 1e-9 and -0.2 - rr.VIEW_MARGIN_M >= x - 1.2 - 1e-9
    assert rr.lookat_x(0.0, -2.0, 2.0, half) == pytest.approx(0.0)  # wider than the picture: centred


def test_the_camera_follows_a_fallen_catch():
    """Real MuJoCo: the 7 kg catch without a CMRT falls forward and ends with its CoM ~1.2 m ahead of the feet;
    the camera stays home while it stands and ends within the dead zone of the CoM."""
    task = load_task("catch")
    traj = simulate(task, Cmrt.zero(task.clip_s))
    times = np.array([0.5, traj.fall_time_s, traj.time_s[-1]])
    track = rr.camera_track(task, traj, times)
    assert track[0] == rr.CAMERA_HOME_M[0]
    com_end = traj.com_m[-1, 0]
    assert com_end > 0.8 and abs(track[-1] - com_end) <= rr.FOLLOW_DEADZONE_M + 1e-9
    assert track[-1] > track[0] + 0.5


@pytest.fixture(scope="module")
def punch_fall():
    task = load_task("punch")
    traj = simulate(task, Cmrt.zero(task.clip_s))
    return task, traj, evaluate(task, traj)


def test_frame_captions_name_task_curve_verdict_and_clock(punch_fall):
    task, _, score = punch_fall
    assert score.fell and rr.verdict(score) == "lost balance"
    fall = score.fall_time_s
    text = [line for line, _, _ in rr.frame_caption(task, "zero CMRT", score, 1.2)]
    assert text == ["punch T = 0.4 s", "zero CMRT", f"lost balance at {fall:.2f} s", "t = 1.20 s  motion"]
    assert rr.frame_caption(task, "zero CMRT", score, fall)[3][0] == f"t = {fall:.2f} s  balance lost"
    assert rr.frame_caption(task, "zero CMRT", score, 3.0)[3][0] == "t = 3.00 s  after the fall"
    assert rr.frame_caption(task, "zero CMRT", score, 0.8)[3][0] == "t = 0.80 s  before the motion"


def test_caption_draws_the_text_above_the_frame():
    img = np.full((320, 240, 3), 40, np.uint8)
    lines = [("bend T = 0.4 s", overlay.WHITE, True), ("library CMRT", overlay.WHITE, False),
             ("SUCCESS", overlay.GREEN, True), ("t = 1.23 s  motion", overlay.GREY, False)]
    out = overlay.caption(img, lines)
    assert out.shape == (320 + overlay.CAPTION_PX, 240, 3) and (out.shape[0] % 8) == 0  # a video's macro block
    assert np.array_equal(out[overlay.CAPTION_PX:], img)  # the picture itself untouched
    band = out[:overlay.CAPTION_PX]
    for i, (_, color, _) in enumerate(lines):  # each line drawn in its colour on its own row
        rows = band[overlay.PAD_PX + i * overlay.LINE_PX:overlay.PAD_PX + (i + 1) * overlay.LINE_PX]
        assert (np.abs(rows.astype(int) - color).sum(-1) < 10).sum() > 20
    empty = overlay.caption(img, [])[:overlay.CAPTION_PX]
    assert not empty.any()
    long = overlay.caption(img, [("x" * 200, overlay.WHITE, False)])[:overlay.CAPTION_PX]
    assert not long[:, -overlay.PAD_PX + 1:].any()  # a long label is cut, not run off the frame


def test_key_names_the_markers_in_their_colours():
    band = overlay.key_band(240, footprints=True)  # narrow: wraps
    assert band.shape[0] % 8 == 0 and band.shape[0] > overlay.LINE_PX * 2
    for _, color, _ in overlay.KEY + (overlay.FOOTPRINT_KEY,):
        assert (np.abs(band.astype(int) - color).sum(-1) < 10).sum() > 10


def test_filmstrip_of_a_fall_in_process(tmp_path, punch_fall):
    """A real OSMesa render (3 frames): the fall's frame is in it, every panel is captioned in the verdict's
    red and the key sits under the strip."""
    task = punch_fall[0]
    out = tmp_path / "punch.png"
    r = render_clip(task, Cmrt.zero(task.clip_s), out, labels=("zero CMRT", ""), n_frames=3)
    fall = r["clips"][0]["fall_time_s"]
    assert r["clips"][0]["verdict"] == "lost balance" and fall in r["times_s"]
    img = (mpimg.imread(out)[..., :3] * 255).round().astype(int)
    assert img.shape[1] == 3 * 240 + 2 * overlay.GAP_PX
    verdict_row = img[overlay.PAD_PX + 2 * overlay.LINE_PX:overlay.PAD_PX + 3 * overlay.LINE_PX]
    for c in range(3):
        panel = verdict_row[:, c * (240 + overlay.GAP_PX):c * (240 + overlay.GAP_PX) + 240]
        assert (np.abs(panel - overlay.RED).sum(-1) < 10).sum() > 20
    key = img[320 + overlay.CAPTION_PX + overlay.GAP_PX:]
    assert (np.abs(key - overlay.KEY[0][1]).sum(-1) < 10).sum() > 10


def test_the_cop_marker_is_drawn_until_the_fall_and_not_after(punch_fall):
    """After a fall there is no balance to mark: the red CoP disc goes, as the plots' CoP traces end there."""
    import mujoco

    task, traj, score = punch_fall
    m = task.model()
    data = mujoco.MjData(m)
    camera = mujoco.MjvCamera()
    renderer = rr._renderer(m, 120, 90)
    try:
        def red_discs(t):
            k = rr._pose(m, data, traj, t)
            rr._frame(renderer, data, camera, traj, k)
            scene = renderer.scene
            return sum(np.allclose(scene.geoms[i].rgba, rr.RED) for i in range(scene.ngeom))

        before, after = red_discs(score.fall_time_s - 0.3), red_discs(score.fall_time_s + 0.3)
    finally:
        renderer.close()
    assert before == 1 and after == 0


def _scene_on(task, tilt: bool):
    """The start pose's scene in the support's frame, moved to the world (``_to_world``) if ``tilt``."""
    import mujoco

    from cmrt.body.surface import tilt_pose

    m = task.model()
    data = mujoco.MjData(m)
    data.qpos[:] = tilt_pose(m, task.start_qpos(), float(task.support.tilt(0.0)[0]))
    mujoco.mj_forward(m, data)
    scene = mujoco.MjvScene(m, maxgeom=200)
    mujoco.mjv_updateScene(m, data, mujoco.MjvOption(), None, mujoco.MjvCamera(), mujoco.mjtCatBit.mjCAT_ALL,
                           scene)
    if tilt:
        rr._to_world(scene, np.array([float(task.support.tilt(0.0)[0]), 0.0, 0.0]))

    def axis(name):
        i = next(i for i in range(scene.ngeom) if scene.geoms[i].objtype == mujoco.mjtObj.mjOBJ_GEOM
                 and scene.geoms[i].objid == m.geom(name).id)
        return scene.geoms[i].mat.reshape(3, 3)[:, 2]
    return axis


def test_a_tilted_support_is_drawn_tilted_and_the_body_upright():
    """The simulation runs in the support's frame; a picture shows the world: on a 15 degree slope (rising ahead)
    the floor's normal leans back by 15 degrees, and the trunk stands as it does on the level floor."""
    level = _scene_on(load_task("stand"), tilt=False)
    slope = _scene_on(load_task("stand").with_params(slope_deg=15.0), tilt=True)
    normal = slope("floor")
    assert np.degrees(np.arctan2(-normal[0], normal[2])) == pytest.approx(15.0, abs=1e-4)

    def lean_deg(axis):
        return np.degrees(np.arctan(axis[0] / axis[2]))
    assert lean_deg(slope("thorax")) == pytest.approx(lean_deg(level("thorax")), abs=0.01)


def test_a_floating_box_is_drawn_as_a_box_on_water_moving_as_it_did(tmp_path):
    """On the floating box the endless floor is hidden, the box is drawn under the deck, tilted and moved as the
    run left it (``Trajectory.support_pose``), and the water is level in the world."""
    import mujoco

    task = load_task("stand").with_params(box_mass_kg=200.0, clip_s=2.5, push_force_n=150.0, push_start_s=1.0)
    traj = simulate(task)
    k = int(np.argmax(np.abs(traj.support_pose[:, 0])))  # the largest tilt
    assert abs(np.degrees(traj.support_pose[k, 0])) > 1.0
    m = task.model()
    data = mujoco.MjData(m)
    data.qpos[:] = traj.qpos[k]
    mujoco.mj_forward(m, data)
    scene = mujoco.MjvScene(m, maxgeom=300)
    mujoco.mjv_updateScene(m, data, mujoco.MjvOption(), None, mujoco.MjvCamera(), mujoco.mjtCatBit.mjCAT_ALL,
                           scene)
    floor = m.geom("floor").id
    rr._floating_box(scene, m)
    rr._to_world(scene, traj.support_pose[k])
    geoms = [scene.geoms[i] for i in range(scene.ngeom)]
    assert all(g.rgba[3] == 0.0 for g in geoms if g.objtype == mujoco.mjtObj.mjOBJ_GEOM and g.objid == floor)
    box = next(g for g in geoms if np.allclose(g.rgba, rr.WOOD))
    top_normal = box.mat.reshape(3, 3)[:, 2]
    assert np.degrees(np.arctan2(top_normal[0], top_normal[2])) == pytest.approx(
        np.degrees(traj.support_pose[k, 0]), abs=1e-3)
    assert rr.floating_draft_m(task.support) == pytest.approx((200.0 + 70.0) * 9.81 / 9810.0, rel=0.01)


def test_a_keyed_gait_is_framed_and_keyed_as_yus_walk():
    """yu-walk: the filmstrip's window is the gait's (first lift-off to back at standing, then the reaction time),
    its frames are "steps", and the key names Yu's reference CoM instead of the support centre's."""
    task = load_task("yu-walk")
    start, end = rr.motion_window(task)
    assert start == pytest.approx(task.gait.lift_off_s(0)) and task.gait.end_s <= end <= task.clip_s
    assert rr.phase(task, 2.0, None) == "steps"
    yu, center = overlay.key_band(1200, True, "yu"), overlay.key_band(1200, True)
    assert yu.shape == center.shape and not np.array_equal(yu, center)
    assert overlay.YU_REFERENCE_TEXT.startswith("reference CoM")
