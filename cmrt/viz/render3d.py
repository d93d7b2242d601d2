"""Filmstrips of a 3D clip (``cmrt.sim.spatial``): a front view above a side view, so that sideways motion - a
lean, a foot lifting, a fall to the side - shows as clearly as the sagittal one does on the planar body.

The camera stands still, aimed at where the body stood (a fall leaves the frame's centre rather than dragging
the camera along); each frame is captioned with its time and, from the fall on, that the body fell.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from cmrt import inputs
from cmrt.body.character import character
from cmrt.sim.spatial import BODY, StandResult
from cmrt.viz import overlay
from cmrt.viz.render import _renderer

VIEWS = (("front", 180.0), ("side", 90.0))  # (name, camera azimuth deg): facing the body; from its left
DISTANCE_M = 3.4  # camera to the body's standing place: the whole body and a fall's first metre in frame
ELEVATION_DEG = -10.0


def filmstrip_3d(result: StandResult, times_s: np.ndarray, out: str | Path, height: int = 320,
                 width: int = 240) -> dict:
    """Render ``result`` at ``times_s`` (front row over side row) to the PNG ``out``; returns what was written."""
    out = Path(out)
    inputs.check_output(out, "--filmstrip", (".png",))
    m = character(BODY).model
    d = mujoco.MjData(m)
    renderer = _renderer(m, height, width)
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = (result.com_m[0, 0], result.com_m[0, 1], 0.7)
    camera.distance, camera.elevation = DISTANCE_M, ELEVATION_DEG
    rows = []
    try:
        for name, azimuth in VIEWS:
            camera.azimuth = azimuth
            row = []
            for t in times_s:
                k = min(int(np.searchsorted(result.time_s, t)), len(result.time_s) - 1)
                d.qpos[:] = result.qpos[k]
                mujoco.mj_forward(m, d)
                renderer.update_scene(d, camera)
                fallen = result.fall_time_s is not None and result.time_s[k] >= result.fall_time_s
                lines = [(f"{name}  t = {result.time_s[k]:.2f} s", (255, 255, 255), True)]
                lines.append(("fell" if fallen else "standing", (230, 25, 25) if fallen else (25, 205, 50), False))
                row.append(overlay.caption(renderer.render(), lines))
            rows.append(np.concatenate(row, axis=1))
    finally:
        renderer.close()
    with inputs.atomic_output(out, "--filmstrip", (".png",)) as tmp:
        overlay.save_png(np.concatenate(rows, axis=0), tmp)
    return {"out": str(out), "times_s": [round(float(t), 3) for t in times_s], "views": [v for v, _ in VIEWS]}
