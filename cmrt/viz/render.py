"""Offscreen renders of clips with the balance markers of ABC Figs. 7-9.

Markers: the CoM (cyan sphere) and its ground projection (cyan disc), the reference CoM c_r (green
vertical line: s + d(t), or Yu's eq. 3.2 + d(t)) and the measured CoP (red disc). Every frame carries a caption
(``cmrt.viz.overlay``): the task, the curve, the verdict and the clock. A PNG is a filmstrip whose
frames crowd into the motion's window and around a fall (:func:`filmstrip_times`; with ``compare``: the
comparison clip on the top row, as in the paper's "top: without anticipation, bottom: with"); an MP4 is
a video (imageio's ffmpeg plugin) with the two clips side by side. The camera stands still while the body
does and pans after it when its CoM or its limbs would leave the picture (:func:`lookat_x`).

OpenGL is loaded here, when the first frame is rendered, and nowhere else (``cmrt/__init__`` has MuJoCo
imported with GL disabled, so that simulating never needs it): the user's ``MUJOCO_GL`` if set (kept in
``CMRT_MUJOCO_GL``), else EGL where a GPU device exists, else OSMesa (``apt-get install libosmesa6``;
PyOpenGL from pip). A backend that cannot load is one line, exit 2.
"""

from __future__ import annotations

import importlib
import os
import sys
from pathlib import Path

import mujoco
import numpy as np

from cmrt import inputs
from cmrt.body.character import GRAVITY_M_S2, character
from cmrt.body.floating_box import BOX_HEIGHT_M, BOX_WIDTH_M
from cmrt.body.surface import lean_x, pose_matrix
from cmrt.errors import CmrtError
from cmrt.motion.curve import Cmrt
from cmrt.motion.footsteps import timeline
from cmrt.motion.task import Task
from cmrt.sim.objective import Evaluation, evaluate
from cmrt.sim.simulate import Trajectory, simulate
from cmrt.viz import overlay

CYAN = np.array([0.1, 0.8, 0.9, 1.0], dtype=np.float32)
GREEN = np.array([0.1, 0.8, 0.2, 1.0], dtype=np.float32)
RED = np.array([0.9, 0.1, 0.1, 1.0], dtype=np.float32)
AMBER = np.array([0.95, 0.6, 0.1, 0.8], dtype=np.float32)
WOOD = np.array([0.55, 0.38, 0.2, 1.0], dtype=np.float32)
WATER = np.array([0.2, 0.45, 0.8, 0.45], dtype=np.float32)
FOOTPRINT_HALF_M = (0.12, 0.05, 0.002)  # half length (heel point to toe point / 2), half width, half height
MARKER_Y_M = -0.35  # the camera looks along +y from the -y side
OUT_SUFFIXES = (".png", ".mp4")
VIDEO_CHUNK = 64  # video frames rendered at a time per clip: memory stays ~15 MB per clip however long the clip
CAMERA_HOME_M = (0.05, 0.0, 0.8)  # where the camera looks while the body stands
CAMERA_DISTANCE_M, CAMERA_AZIMUTH_DEG, CAMERA_ELEVATION_DEG = 3.2, 90.0, -8.0
FOLLOW_DEADZONE_M = 0.15  # the camera stays home while the CoM is this close to it, then follows it
VIEW_MARGIN_M = 0.1  # kept between the body's horizontal extent and the picture's edge
FILMSTRIP_LEAD_S = 0.2  # a filmstrip starts this long before the motion: the pose it starts from
MOTION_DENSITY = 6.0  # a filmstrip's frames per second inside the motion's window, relative to outside it
FALL_DENSITY = 4.0  # ... and from FALL_BEFORE_S before a fall to FALL_AFTER_S after it
FALL_BEFORE_S, FALL_AFTER_S = 0.2, 0.3
PUSH_REACTION_S = 0.5  # a task without a pose change: its window is the pushes and this long after the last


GL_BACKENDS = ("egl", "osmesa", "glfw", "glx")  # what MuJoCo's Python bindings can use offscreen on Linux


def gl_backend() -> str:
    """The OpenGL backend rendering uses: the user's ``MUJOCO_GL``, else EGL with a GPU device, else OSMesa."""
    requested = (os.environ.get("CMRT_MUJOCO_GL") or "").lower().strip()
    if requested:
        return requested
    gpu = os.path.exists("/dev/nvidia0") or any(os.path.exists(f"/dev/dri/renderD{i}") for i in range(128, 136))
    return "egl" if gpu else "osmesa"


def _gl_hint(backend: str) -> str:
    return ("install OSMesa (apt-get install libosmesa6) and PyOpenGL" if backend == "osmesa"
            else "check the GPU's EGL driver, or set MUJOCO_GL=osmesa with libosmesa6 installed")


def _load_gl() -> None:
    """Give MuJoCo's renderer an OpenGL context class, loaded now (see the module docstring). MuJoCo's
    ``Renderer`` looks the class up in its ``gl_context`` module when it is built."""
    gl_context = importlib.import_module(mujoco.Renderer.__module__).gl_context
    existing = getattr(gl_context, "GLContext", None)
    if existing is not None and not _headless_default(existing):
        return  # loaded already, or chosen by mujoco itself (imported before cmrt)
    backend = gl_backend()
    if backend not in GL_BACKENDS:
        raise CmrtError(f"cannot render: MUJOCO_GL={backend} is not one of {', '.join(GL_BACKENDS)}")
    try:
        if backend == "egl":
            from mujoco.egl import GLContext
        elif backend == "osmesa":
            from mujoco.osmesa import GLContext
        else:
            from mujoco.glfw import GLContext
    except Exception as exc:  # ImportError, OSError, or PyOpenGL's AttributeError on a library it could not load
        raise CmrtError(f"cannot render: OpenGL backend {backend} does not load ({type(exc).__name__}: "
                        f"{exc}); {_gl_hint(backend)}") from None
    gl_context.GLContext = GLContext


def _headless_default(context_class: type) -> bool:
    """MuJoCo imported before cmrt with no ``MUJOCO_GL`` picks GLFW, which needs a display: on a machine
    without one (``$DISPLAY`` unset) that is MuJoCo's default, not a choice, and cmrt loads its own backend
    instead (a script doing ``import mujoco`` first - as the tests' conftest does - could not render)."""
    chosen = os.environ.get("MUJOCO_GL", "").lower() not in ("", "disable")
    return context_class.__module__.startswith("mujoco.glfw") and not chosen and not os.environ.get("DISPLAY")


def _renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    _load_gl()
    try:
        return mujoco.Renderer(model, height, width)
    except Exception as exc:  # FatalError, ctypes errors: all mean "no OpenGL context here"
        backend = gl_backend()
        raise CmrtError(f"cannot render with MUJOCO_GL={backend}: {type(exc).__name__}: {exc}; "
                        f"{_gl_hint(backend)}") from None


def _add_geom(scene: mujoco.MjvScene, gtype, size, pos, rgba, mat=None) -> None:
    if scene.ngeom >= scene.maxgeom:
        return
    g = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(g, gtype, np.asarray(size, float), np.asarray(pos, float),
                        np.eye(3).ravel() if mat is None else mat, rgba)
    scene.ngeom += 1


def _to_world(scene: mujoco.MjvScene, pose: np.ndarray, upright: tuple[int, ...] = ()) -> None:
    """Every geom of a scene built in the support's frame (the simulation's) placed where the support is
    (``pose``: tilt, x, z; ``Trajectory.support_pose``): a slope or a tilting plane is drawn tilted, a moving
    platform moved, the character on it. The geoms ``upright`` (a vertical marker) are moved but stay vertical
    in the world."""
    rot, shift = pose_matrix(*(float(v) for v in pose))
    for i in range(scene.ngeom):
        g = scene.geoms[i]
        g.pos[:] = rot @ g.pos + shift
        if i not in upright:
            g.mat[:] = rot @ g.mat.reshape(3, 3)


def _frame(renderer, data, camera, traj: Trajectory, k: int, draft_m: float | None = None) -> np.ndarray:
    """One picture of step ``k``; ``draft_m``: on a floating box, how deep it floats at rest (None: not one)."""
    renderer.update_scene(data, camera)
    scene = renderer.scene
    com = data.subtree_com[1]
    y = MARKER_Y_M  # markers sit between the body and the camera so they are never hidden
    # on a tilted support the ground points are along gravity: the CoM's over the CoP it balances on
    pose = None if traj.support_pose is None else traj.support_pose[k]
    lean = 0.0 if pose is None else float(lean_x(pose[0], com[2]))
    _add_geom(scene, mujoco.mjtGeom.mjGEOM_SPHERE, [0.035, 0, 0], [com[0], y, com[2]], CYAN)
    _add_geom(scene, mujoco.mjtGeom.mjGEOM_CYLINDER, [0.04, 0.003, 0], [com[0] - lean, y, 0.003], CYAN)
    ref = traj.com_ref_x_m[k]
    upright = ()
    if np.isfinite(ref):
        upright = (scene.ngeom,)
        theta = 0.0 if pose is None else float(pose[0])
        up = (-np.sin(theta), np.cos(theta))  # the world's vertical in the support's frame: the line stands on
        _add_geom(scene, mujoco.mjtGeom.mjGEOM_CAPSULE, [0.008, 0.6, 0],  # its ground point, upright in the world
                  [ref - lean + 0.6 * up[0], y, 0.6 * up[1]], GREEN)
    cop = traj.cop_x_m[k]
    fallen = traj.fall_time_s is not None and traj.time_s[k] > traj.fall_time_s + 1e-9
    if np.isfinite(cop) and not fallen:  # after the fall there is no balance to mark (as the plots stop there)
        _add_geom(scene, mujoco.mjtGeom.mjGEOM_CYLINDER, [0.03, 0.005, 0], [cop, y, 0.008], RED)
    for _foot, landed_s, heel_x in traj.footprints:  # where each step of a stepping task landed
        if landed_s <= traj.time_s[k]:
            _add_geom(scene, mujoco.mjtGeom.mjGEOM_BOX, FOOTPRINT_HALF_M,
                      [heel_x + FOOTPRINT_HALF_M[0], y, FOOTPRINT_HALF_M[2]], AMBER)
    if draft_m is not None:  # the deck is the box's top, not an endless floor
        _floating_box(scene, renderer.model)
    if pose is not None:
        _to_world(scene, pose, upright)
    if draft_m is not None:  # still water where the box floats at rest, in the world (a thin slab)
        _add_geom(scene, mujoco.mjtGeom.mjGEOM_BOX, [6.0, 2.0, 0.002], [0.0, 0.0, -draft_m], WATER)
    return renderer.render().copy()


def floating_draft_m(support) -> float:
    """How deep a floating box sits at rest with the character on it (buoyancy = weight), for the picture."""
    return min(0.9 * BOX_HEIGHT_M, (support.box_mass_kg + character().mass_kg) * GRAVITY_M_S2
               / support.box_stiffness_n_m)


def _floating_box(scene: mujoco.MjvScene, model: mujoco.MjModel) -> None:
    """Hide the floor plane and draw the box under the deck, in the deck's frame (moved with it)."""
    floor = model.geom("floor").id
    for i in range(scene.ngeom):
        g = scene.geoms[i]
        if g.objtype == mujoco.mjtObj.mjOBJ_GEOM and g.objid == floor:
            g.rgba[3] = 0.0
    _add_geom(scene, mujoco.mjtGeom.mjGEOM_BOX, [BOX_WIDTH_M / 2, 0.5, BOX_HEIGHT_M / 2],
              [0.0, 0.0, -BOX_HEIGHT_M / 2], WOOD)


def verdict(score: Evaluation) -> str:
    """A clip's verdict in words, as ``cmrt render`` prints it and every frame shows it: the rules it broke."""
    if score.success:
        return "SUCCESS"
    if score.fell:
        return "lost balance"
    return "balance kept, not a success: " + ", ".join(r.replace("_", " ") for r in score.failed_rules)


def task_label(task: Task) -> str:
    """The task and its speed, e.g. ``bend T = 0.4 s``."""
    if task.speed is None:
        return task.name
    if task.speed_param == "duration_s":
        return f"{task.name} T = {task.speed:g} s"
    return f"{task.name} {task.speed_param} = {task.speed:g}"


def motion_window(task: Task) -> tuple[float, float]:
    """When the task happens: [P, P + T] for a pose change; else from the first push (or planned step) to
    ``PUSH_REACTION_S`` after the last push (the last planned landing); else (nothing happens) the whole clip."""
    if task.duration_s > 0:
        return task.task_window_s()
    t = np.arange(0.0, task.clip_s, 0.005)
    pushed = t[task.pushes_n(t) != 0]
    spans = [(float(pushed[0]), float(pushed[-1]))] if pushed.size else []
    if task.steps:  # the steps as planned (they may land a little later)
        steps = timeline(task.plan)
        spans.append((steps[0][0], steps[-1][1]))
    if task.gait is not None:  # a keyed gait: from its first lift-off until it is back to standing
        spans.append((task.gait.lift_off_s(0), task.gait.end_s))
    if spans:
        return min(a for a, _ in spans), min(max(b for _, b in spans) + PUSH_REACTION_S, task.clip_s)
    return 0.0, task.clip_s


def filmstrip_times(window: tuple[float, float], falls: list[float], end_s: float, n: int) -> np.ndarray:
    """``n`` frame times from ``FILMSTRIP_LEAD_S`` before the motion's ``window`` to ``end_s``, spaced by a
    density ``MOTION_DENSITY`` times higher inside the window and ``FALL_DENSITY`` times higher about each
    fall; each fall's own time replaces the frame nearest it. Times in 0.01 s (a fall's exact)."""
    lo, hi = window
    start = max(0.0, min(lo - FILMSTRIP_LEAD_S, end_s))
    grid = np.linspace(start, end_s, 4001)
    density = np.where((grid >= lo) & (grid <= hi), MOTION_DENSITY, 1.0)
    for f in falls:
        density = np.where((grid >= f - FALL_BEFORE_S) & (grid <= f + FALL_AFTER_S),
                           np.maximum(density, FALL_DENSITY), density)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(grid))])
    times = np.round(np.interp(np.linspace(0.0, cdf[-1], n) if n > 1 else [cdf[-1] / 2], cdf, grid), 2)
    fixed = np.zeros(times.size, bool)
    for f in sorted(falls)[:n]:
        k = np.argmin(np.where(fixed, np.inf, np.abs(times - f)))
        times[k], fixed[k] = f, True
    return np.sort(times)


def phase(task: Task, t: float, fall_s: float | None) -> str:
    """What the clip is doing at ``t``: before / motion (or push) / after, standing tail; balance lost (the
    fall's own frame), after the fall."""
    if fall_s is not None and t >= fall_s - 5e-4:
        return "balance lost" if t < fall_s + 5e-3 else "after the fall"
    if t > task.clip_s:
        return "standing tail"
    lo, hi = motion_window(task)
    if (lo, hi) == (0.0, task.clip_s):
        return ""
    name = "motion" if task.duration_s > 0 else "steps" if task.steps or task.gait is not None else "push"
    return f"before the {name}" if t < lo else name if t <= hi else f"after the {name}"


def frame_caption(task: Task, label: str, score: Evaluation, t: float) -> list[tuple[str, tuple, bool]]:
    """The lines burned above a frame (text, colour, bold): task, curve, verdict, clock."""
    fall_s = score.fall_time_s if score.fell else None
    color = overlay.GREEN if score.success else overlay.RED if score.fell else overlay.AMBER
    what = phase(task, t, fall_s)
    clock = overlay.RED if what in ("balance lost", "after the fall") else overlay.GREY
    return [(task_label(task), overlay.WHITE, True), (label or "CMRT", overlay.WHITE, False),
            (verdict(score) + (f" at {fall_s:.2f} s" if fall_s is not None else ""), color, True),
            (f"t = {t:.2f} s" + (f"  {what}" if what else ""), clock, False)]


def half_view_m(model: mujoco.MjModel, height: int, width: int) -> float:
    """Half the picture's width at the body's depth (m)."""
    return CAMERA_DISTANCE_M * float(np.tan(np.radians(model.vis.global_.fovy) / 2)) * width / height


def lookat_x(com_x: float, lo_x: float, hi_x: float, half_view: float) -> float:
    """Where the camera looks: home while the CoM is within ``FOLLOW_DEADZONE_M`` of it, else that far
    behind the CoM; then moved so the body's extent [lo_x, hi_x] (plus ``VIEW_MARGIN_M``) is in the picture,
    or centred on it when it is wider than the picture."""
    home = CAMERA_HOME_M[0]
    x = home + float(np.sign(com_x - home)) * max(abs(com_x - home) - FOLLOW_DEADZONE_M, 0.0)
    lo_x, hi_x = lo_x - VIEW_MARGIN_M, hi_x + VIEW_MARGIN_M
    if hi_x - lo_x >= 2 * half_view:
        return (lo_x + hi_x) / 2
    return min(max(x, hi_x - half_view), lo_x + half_view)


def _pose(m: mujoco.MjModel, data: mujoco.MjData, traj: Trajectory, t: float) -> int:
    k = min(int(round(t / m.opt.timestep)), traj.time_s.size - 1)
    data.qpos[:] = traj.qpos[k]
    mujoco.mj_forward(m, data)
    return k


def _aim(m: mujoco.MjModel, data: mujoco.MjData, half_view: float) -> float:
    """The camera's lookat x for the pose in ``data`` (the humanoid's geoms bound its extent)."""
    geoms = np.flatnonzero(m.body_rootid[m.geom_bodyid] == 1)
    x, r = data.geom_xpos[geoms, 0], m.geom_rbound[geoms]
    return lookat_x(float(data.subtree_com[1][0]), float((x - r).min()), float((x + r).max()), half_view)


def camera_track(task: Task, traj: Trajectory, times_s, height: int = 320, width: int = 240) -> np.ndarray:
    """The camera's lookat x at ``times_s`` (what :func:`render_frames` uses), without rendering."""
    m = task.model()
    data = mujoco.MjData(m)
    half = half_view_m(m, height, width)
    out = []
    for t in times_s:
        _pose(m, data, traj, t)
        out.append(_aim(m, data, half))
    return np.array(out)


def render_frames(task: Task, traj: Trajectory, times_s: np.ndarray, height: int, width: int, progress=None):
    """Images of ``traj`` at ``times_s`` (a clip cut short by a fall holds its last pose), the camera
    following the body (:func:`lookat_x`)."""
    m = task.model()
    data = mujoco.MjData(m)
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = CAMERA_HOME_M
    camera.distance, camera.azimuth, camera.elevation = CAMERA_DISTANCE_M, CAMERA_AZIMUTH_DEG, CAMERA_ELEVATION_DEG
    half = half_view_m(m, height, width)
    draft_m = floating_draft_m(task.support) if task.support.floating else None
    renderer = _renderer(m, height, width)
    frames = []
    try:
        for t in times_s:
            k = _pose(m, data, traj, t)
            camera.lookat[0] = _aim(m, data, half)
            if traj.support_pose is not None:  # the camera follows the body in the world
                rot, shift = pose_matrix(*(float(v) for v in traj.support_pose[k]))
                aim = rot @ np.array([camera.lookat[0], 0.0, CAMERA_HOME_M[2]]) + shift
                camera.lookat[0], camera.lookat[2] = aim[0], aim[2]
            frames.append(_frame(renderer, data, camera, traj, k, draft_m))
            if progress:
                progress.update(1)
    finally:
        renderer.close()
    return frames


def _captioned(task: Task, frames, times, label: str, score: Evaluation) -> list[np.ndarray]:
    return [overlay.caption(img, frame_caption(task, label, score, float(t))) for img, t in zip(frames, times,
                                                                                                strict=True)]


def render(
    task: Task, curve: Cmrt, out: str | Path, compare: Cmrt | None = None, labels: tuple[str, str] = ("", ""),
    n_frames: int = 8, fps: int = 30, height: int = 320, width: int = 240,
) -> dict:
    """Render ``task`` with ``curve`` (and ``compare`` above it) to a PNG filmstrip or an MP4."""
    from tqdm import tqdm

    out = Path(out)
    inputs.check_output(out, "--out", OUT_SUFFIXES)  # before anything is simulated
    video = out.suffix.lower() == ".mp4"
    clips = [(compare, labels[1])] if compare is not None else []
    clips.append((curve, labels[0]))
    trajs = [simulate(task, c) for c, _ in clips]  # recorded: past a fall, the topple plays out
    scores = [evaluate(task, tr) for tr in trajs]
    end_s = max(tr.time_s[-1] for tr in trajs)  # the clip, its standing tail, or a topple
    falls = sorted({s.fall_time_s for s in scores if s.fell and s.fall_time_s is not None})
    if not video:
        times = filmstrip_times(motion_window(task), falls, end_s, n_frames)
    else:
        times = np.arange(0.0, end_s, 1.0 / fps)
    footprints = any(tr.footprints for tr in trajs)
    with tqdm(total=len(times) * len(trajs), desc="render", unit="frame", file=sys.stderr,
              disable=not sys.stderr.isatty()) as bar, inputs.atomic_output(out, "--out", OUT_SUFFIXES) as tmp:
        if not video:
            rows = [_captioned(task, render_frames(task, tr, times, height, width, bar), times, lab, s)
                    for tr, (_, lab), s in zip(trajs, clips, scores, strict=True)]
            overlay.save_png(overlay.tile(rows, footprints, task.reference_mode), tmp)
        else:
            _video(tmp, task, trajs, [(lab, s) for (_, lab), s in zip(clips, scores, strict=True)], times, fps,
                   (height, width), bar, footprints)
    return {"out": str(out), "frames": len(times), "times_s": [round(float(t), 3) for t in times] if not video
            else None, "clips": [
        {"label": lab, "verdict": verdict(s), "success": s.success, "fell": s.fell, "fall_time_s": s.fall_time_s,
         "objective": s.objective} for (_, lab), s in zip(clips, scores, strict=True)]}


def _video(out: Path, task: Task, trajs, captions, times, fps: int, size: tuple[int, int], bar,
           footprints: bool) -> None:
    """The clips side by side as an MP4, rendered ``VIDEO_CHUNK`` frames at a time, each frame captioned and the
    markers' key under them."""
    key = overlay.key_band(size[1] * len(trajs), footprints, task.reference_mode)

    def frames():
        for start in range(0, len(times), VIDEO_CHUNK):
            chunk = times[start:start + VIDEO_CHUNK]
            rows = [_captioned(task, render_frames(task, tr, chunk, *size, bar), chunk, lab, s)
                    for tr, (lab, s) in zip(trajs, captions, strict=True)]
            for i in range(len(chunk)):
                yield np.concatenate([np.concatenate([row[i] for row in rows], axis=1), key])

    write_video(out, frames(), fps)


def write_video(out: Path, frames, fps: int) -> None:
    """``frames`` (an iterable of equal-sized RGB images) as an H.264 MP4 (imageio's ffmpeg plugin)."""
    import imageio.v2 as imageio

    try:
        with imageio.get_writer(out, format="FFMPEG", fps=fps, codec="libx264", quality=7,
                                macro_block_size=8) as writer:
            for frame in frames:
                writer.append_data(frame)
    except (RuntimeError, ValueError) as exc:  # ffmpeg missing or failing
        raise CmrtError(f"cannot write the video: {type(exc).__name__}: {str(exc).splitlines()[0]}") from None
