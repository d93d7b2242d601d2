"""Filmstrips and videos of a 3D clip (``cmrt.sim.spatial``): a front view above a side view, so that sideways
motion - a lean, a foot lifting, a fall to the side - shows as clearly as the sagittal one does on the planar body.
A video puts each clip's two views in a column, the clips side by side.

The camera stands still, aimed at where the body stood (a fall leaves the frame's centre rather than dragging
the camera along); each frame is captioned with its time and, from the fall on, that the body fell.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from cmrt import inputs
from cmrt.body.character import character
from cmrt.motion.curve import Cmrt
from cmrt.motion.task import Task
from cmrt.sim.clip3d import clip_3d
from cmrt.sim.spatial import BODY, StandResult
from cmrt.viz import overlay
from cmrt.viz.render import OUT_SUFFIXES, VIDEO_CHUNK, _renderer, filmstrip_times, verdict, write_video

VIEWS = (("front", 180.0), ("side", 90.0))  # (name, camera azimuth deg): facing the body; from its left
# ... and for a task whose prop stands in front of the body (a slab, a heavy bag), which hides it from the front: the
# sideways motion seen from behind (left and right mirrored)
BEHIND = (("back", 0.0), ("side", 90.0))
PROPS_IN_FRONT = ("slab", "bag")
DISTANCE_M = 3.4  # camera to the body's standing place: the whole body and a fall's first metre in frame
ELEVATION_DEG = -10.0


def filmstrip_3d(result: StandResult, times_s: np.ndarray, out: str | Path, height: int = 320,
                 width: int = 240) -> dict:
    """Render ``result`` at ``times_s`` (front row over side row) to the PNG ``out``; returns what was written."""
    out = Path(out)
    inputs.check_output(out, "--filmstrip", (".png",))
    rows = _view_rows(result, times_s, height, width)
    with inputs.atomic_output(out, "--filmstrip", (".png",)) as tmp:
        overlay.save_png(np.concatenate(rows, axis=0), tmp)
    return {"out": str(out), "times_s": [round(float(t), 3) for t in times_s], "views": [v for v, _ in VIEWS]}


def render_3d(task: Task, curve: Cmrt, out: str | Path, compare: Cmrt | None = None,
              labels: tuple[str, str] = ("", ""), n_frames: int = 8, height: int = 320, width: int = 240,
              fps: int = 30) -> dict:
    """``cmrt render`` on a 3D task: each clip (``compare``'s first) as a front row over a side row, captioned
    with its CMRT and verdict, to a PNG filmstrip (the frames denser over the motion and about a fall) or an MP4
    (``fps`` frames a second over the whole clip; each clip a column of its two views). A prop in front of the
    body (``PROPS_IN_FRONT``) turns the front view into one from behind."""
    out = Path(out)
    inputs.check_output(out, "--out", OUT_SUFFIXES)  # before anything is simulated
    clips = ([(compare, labels[1])] if compare is not None else []) + [(curve, labels[0])]
    scored = [(clip_3d(task, c), label) for c, label in clips]
    p = task.params
    falls = sorted({c.result.fall_time_s for c, _ in scored if c.fell})
    video = out.suffix.lower() == ".mp4"
    times = (np.arange(0.0, min(c.result.time_s[-1] for c, _ in scored), 1.0 / fps) if video else
             filmstrip_times((p["preparation_s"], p["preparation_s"] + p["duration_s"]), falls, p["clip_s"], n_frames))
    captions = [f"{label}: {verdict(c.evaluation())}" for c, label in scored]
    views = BEHIND if task.prop in PROPS_IN_FRONT else VIEWS
    with inputs.atomic_output(out, "--out", OUT_SUFFIXES) as tmp:
        if video:
            write_video(tmp, _video_frames([c.result for c, _ in scored], captions, times, height, width,
                                           task.model(), views), fps)
        else:
            rows = [row for (c, _), caption in zip(scored, captions, strict=True)
                    for row in _view_rows(c.result, times, height, width, caption, task.model(), views)]
            overlay.save_png(np.concatenate(rows, axis=0), tmp)
    return {"out": str(out), "frames": len(times), "times_s": None if video else [round(float(t), 3) for t in times],
            "views": [v for v, _ in views], "clips": [
                {"label": label, "verdict": verdict(c.evaluation()), "success": c.success,
                 "failed_rules": list(c.failed_rules), "fell": c.fell,
                 "fall_time_s": c.result.fall_time_s, "objective": c.objective} for c, label in scored]}


def _video_frames(results: list[StandResult], captions: list[str], times_s: np.ndarray, height: int, width: int,
                  model: mujoco.MjModel, views: tuple[tuple[str, float], ...] = VIEWS):
    """The video's frames, ``VIDEO_CHUNK`` times at a time: each clip's front view over its side view, side by
    side."""
    for start in range(0, len(times_s), VIDEO_CHUNK):
        chunk = times_s[start:start + VIDEO_CHUNK]
        frames = [_view_frames(r, chunk, height, width, caption, model, views)
                  for r, caption in zip(results, captions, strict=True)]
        for i in range(len(chunk)):
            yield np.concatenate([np.concatenate([v[i] for v in clip], axis=0) for clip in frames], axis=1)


def _view_rows(result: StandResult, times_s: np.ndarray, height: int, width: int, label: str = "",
               model: mujoco.MjModel | None = None, views: tuple[tuple[str, float], ...] = VIEWS
               ) -> list[np.ndarray]:
    """One row of frames per view (``VIEWS``) of ``result`` at ``times_s`` (``_view_frames`` side by side)."""
    return [np.concatenate(view, axis=1)
            for view in _view_frames(result, times_s, height, width, label, model, views)]


def _view_frames(result: StandResult, times_s: np.ndarray, height: int, width: int, label: str = "",
                 model: mujoco.MjModel | None = None, views: tuple[tuple[str, float], ...] = VIEWS
                 ) -> list[list[np.ndarray]]:
    """Per view (``views``), the frames of ``result`` at ``times_s``, each captioned with the view, the time,
    ``label`` and whether the body has fallen; ``model``: the clip's (a task's prop drawn with the body; default
    the body alone)."""
    m = character(BODY).model if model is None else model
    d = mujoco.MjData(m)
    renderer = _renderer(m, height, width)
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = (result.com_m[0, 0], result.com_m[0, 1], 0.7)
    camera.distance, camera.elevation = DISTANCE_M, ELEVATION_DEG
    frames = []
    try:
        for name, azimuth in views:
            camera.azimuth = azimuth
            row = []
            for t in times_s:
                k = min(int(np.searchsorted(result.time_s, t)), len(result.time_s) - 1)
                d.qpos[:] = result.qpos[k]
                mujoco.mj_forward(m, d)
                renderer.update_scene(d, camera)
                fallen = result.fall_time_s is not None and result.time_s[k] >= result.fall_time_s
                lines = [(f"{name}  t = {result.time_s[k]:.2f} s", (255, 255, 255), True)]
                if label:
                    lines.append((label, (255, 255, 255), False))
                lines.append(("fell" if fallen else "standing", (230, 25, 25) if fallen else (25, 205, 50), False))
                row.append(overlay.caption(renderer.render(), lines))
            frames.append(row)
    finally:
        renderer.close()
    return frames
