"""Offscreen renders of clips with the balance markers of ABC Figs. 7-9.

Markers: the CoM (cyan sphere) and its ground projection (cyan disc), the reference CoM
c_r = s + d(t) (green vertical line) and the measured CoP (red disc). A PNG is a
filmstrip of evenly spaced frames (with ``compare``: the comparison clip on the top row,
as in the paper's "top: without anticipation, bottom: with"); an MP4 is a video
(imageio's ffmpeg plugin) with the two clips side by side.

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
from cmrt.errors import CmrtError
from cmrt.motion.curve import Cmrt
from cmrt.motion.task import Task
from cmrt.sim.objective import evaluate
from cmrt.sim.simulate import Trajectory, simulate

CYAN = np.array([0.1, 0.8, 0.9, 1.0], dtype=np.float32)
GREEN = np.array([0.1, 0.8, 0.2, 1.0], dtype=np.float32)
RED = np.array([0.9, 0.1, 0.1, 1.0], dtype=np.float32)
AMBER = np.array([0.95, 0.6, 0.1, 0.8], dtype=np.float32)
FOOTPRINT_HALF_M = (0.12, 0.05, 0.002)  # half length (heel point to toe point / 2), half width, half height
MARKER_Y_M = -0.35  # the camera looks along +y from the -y side
OUT_SUFFIXES = (".png", ".mp4")
VIDEO_CHUNK = 64  # video frames rendered at a time per clip: memory stays ~15 MB per clip however long the clip


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
    if getattr(gl_context, "GLContext", None) is not None:
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


def _frame(renderer, data, camera, traj: Trajectory, k: int) -> np.ndarray:
    renderer.update_scene(data, camera)
    scene = renderer.scene
    com = data.subtree_com[1]
    y = MARKER_Y_M  # markers sit between the body and the camera so they are never hidden
    _add_geom(scene, mujoco.mjtGeom.mjGEOM_SPHERE, [0.035, 0, 0], [com[0], y, com[2]], CYAN)
    _add_geom(scene, mujoco.mjtGeom.mjGEOM_CYLINDER, [0.04, 0.003, 0], [com[0], y, 0.003], CYAN)
    ref = traj.com_ref_x_m[k]
    if np.isfinite(ref):
        _add_geom(scene, mujoco.mjtGeom.mjGEOM_CAPSULE, [0.008, 0.6, 0], [ref, y, 0.6], GREEN)
    cop = traj.cop_x_m[k]
    if np.isfinite(cop):
        _add_geom(scene, mujoco.mjtGeom.mjGEOM_CYLINDER, [0.03, 0.005, 0], [cop, y, 0.008], RED)
    for _foot, landed_s, heel_x in traj.footprints:  # where each step of a stepping task landed
        if landed_s <= traj.time_s[k]:
            _add_geom(scene, mujoco.mjtGeom.mjGEOM_BOX, FOOTPRINT_HALF_M,
                      [heel_x + FOOTPRINT_HALF_M[0], y, FOOTPRINT_HALF_M[2]], AMBER)
    return renderer.render().copy()


def render_frames(task: Task, traj: Trajectory, times_s: np.ndarray, height: int, width: int, progress=None):
    """Images of ``traj`` at ``times_s`` (a clip cut short by a fall holds its last pose)."""
    m = task.model()
    data = mujoco.MjData(m)
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = [0.05, 0.0, 0.8]
    camera.distance, camera.azimuth, camera.elevation = 3.2, 90.0, -8.0
    renderer = _renderer(m, height, width)
    frames = []
    try:
        for t in times_s:
            k = min(int(round(t / m.opt.timestep)), traj.time_s.size - 1)
            data.qpos[:] = traj.qpos[k]
            mujoco.mj_forward(m, data)
            frames.append(_frame(renderer, data, camera, traj, k))
            if progress:
                progress.update(1)
    finally:
        renderer.close()
    return frames


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
    if not video:
        times = np.linspace(max(0.0, task.preparation_s - 0.2), end_s, n_frames)
    else:
        times = np.arange(0.0, end_s, 1.0 / fps)
    with tqdm(total=len(times) * len(trajs), desc="render", unit="frame", file=sys.stderr,
              disable=not sys.stderr.isatty()) as bar, inputs.atomic_output(out, "--out", OUT_SUFFIXES) as tmp:
        if not video:
            rows = [render_frames(task, tr, times, height, width, bar) for tr in trajs]
            _filmstrip(tmp, rows, times, [lab for _, lab in clips], scores)
        else:
            _video(tmp, task, trajs, times, fps, height, width, bar)
    return {"out": str(out), "frames": len(times), "clips": [
        {"label": lab, "success": s.success, "fell": s.fell, "fall_time_s": s.fall_time_s, "objective": s.objective}
        for (_, lab), s in zip(clips, scores, strict=True)]}


def _video(out: Path, task: Task, trajs, times, fps: int, height: int, width: int, bar) -> None:
    """The clips side by side as an MP4 (imageio's ffmpeg), rendered ``VIDEO_CHUNK`` frames at a time."""
    import imageio.v2 as imageio

    try:
        with imageio.get_writer(out, format="FFMPEG", fps=fps, codec="libx264", quality=7,
                                macro_block_size=8) as writer:
            for start in range(0, len(times), VIDEO_CHUNK):
                chunk = times[start:start + VIDEO_CHUNK]
                rows = [render_frames(task, tr, chunk, height, width, bar) for tr in trajs]
                for i in range(len(chunk)):
                    writer.append_data(np.concatenate([row[i] for row in rows], axis=1))
    except (RuntimeError, ValueError) as exc:  # ffmpeg missing or failing
        raise CmrtError(f"cannot write the video: {type(exc).__name__}: {str(exc).splitlines()[0]}") from None


def _filmstrip(out: Path, rows, times, labels, scores) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n_rows, n_cols = len(rows), len(times)
    fig, axes = plt.subplots(n_rows, n_cols, figsize=(1.6 * n_cols, 2.3 * n_rows), squeeze=False)
    for r, (row, label, score) in enumerate(zip(rows, labels, scores, strict=True)):
        status = ("success" if score.success else
                  f"fell at {score.fall_time_s:.2f} s" if score.fell else "not a success")
        for c, img in enumerate(row):
            ax = axes[r, c]
            ax.imshow(img)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{times[c]:.2f} s", fontsize=8)
        axes[r, 0].set_ylabel(f"{label}\n{status}", fontsize=9)
    fig.tight_layout()
    try:
        fig.savefig(out, dpi=110, format="png")
    finally:
        plt.close(fig)
