"""The reference motion of a task: each joint eased from pose to pose over the task phase [P, P + T].

``Task.reference``, ``Task.keyframes`` and ``Task.joint_windows`` are these functions.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import TYPE_CHECKING

import numpy as np

from cmrt.body.character import SIDED_JOINTS, character

if TYPE_CHECKING:
    from cmrt.motion.task import Task


def smoothstep5(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quintic ease-in-ease-out on [0, 1]: value, d/ds, d2/ds2 (zero rate and acceleration at both ends)."""
    s = np.clip(s, 0.0, 1.0)
    return (
        s**3 * (10 - 15 * s + 6 * s**2),
        30 * s**2 * (1 - s) ** 2,
        60 * s * (1 - s) * (1 - 2 * s),
    )


def keyframes(task: Task) -> list[tuple[float, np.ndarray]]:
    """(fraction of T, qpos) of the poses the motion passes: start, [via], end."""
    keys = [(0.0, task.start_qpos())]
    if task.via_pose_deg is not None:
        keys.append((task.params["via_fraction"], task.via_qpos()))
    return keys + [(1.0, task.end_qpos())]


_CACHE: OrderedDict[tuple[str, bytes], tuple[np.ndarray, np.ndarray, np.ndarray]] = OrderedDict()
_CACHE_SIZE = 64  # (task, times) pairs: a clip's steps, its scored samples, their late copies, ensemble timings
_CACHE_LOCK = threading.Lock()  # simulate_batch's threads ask for it at once


def reference(task: Task, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``reference_motion``, remembered per task and times (read-only arrays): every evaluation asks for
    the same clip's reference four times (the controller's, and the objective's tracking error and
    bound), and computing it cost ~15 % of an evaluation's physics."""
    t = np.atleast_1d(np.asarray(t_s, dtype=float))
    key = (task.content_hash(), t.tobytes())
    with _CACHE_LOCK:
        hit = _CACHE.get(key)
        if hit is not None:
            _CACHE.move_to_end(key)
            return hit
    out = reference_motion(task, t)
    for a in out:
        a.flags.writeable = False
    with _CACHE_LOCK:
        _CACHE[key] = out
        while len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
    return out


def reference_motion(task: Task, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference q, qd, qdd at times ``t_s`` (shape (n, nv)).

    Each joint eases from the start to the end pose (through the via pose, if any, at
    ``via_fraction`` of T) over its window of the task phase [P, P + T] (``[timing]``:
    fractions of T, default [0, 1]). The root pitch that keeps the right foot flat,
    -(hip + knee + ankle), follows the leg joints. The root's x and z are not tracked;
    they ease with the hip for completeness.
    """
    t = np.atleast_1d(np.asarray(t_s, dtype=float))
    q0, q1 = task.start_qpos(), task.end_qpos()
    n, nv = len(t), q0.size
    q, qd, qdd = np.tile(q0, (n, 1)), np.zeros((n, nv)), np.zeros((n, nv))
    if task.end_pose_deg is None:
        return q, qd, qdd
    ch = character()
    dq = q1 - q0
    windows = joint_windows(task)
    keys = keyframes(task)
    for (fa, qa), (fb, qb) in zip(keys, keys[1:], strict=False):
        for i, name in enumerate(ch.dof_names):
            a, b = windows.get(name, (0.0, 1.0)) if len(keys) == 2 else (fa, fb)
            span = (b - a) * task.duration_s
            s, ds, dds = smoothstep5((t - task.preparation_s - a * task.duration_s) / span)
            step = qb[i] - qa[i]
            q[:, i] += s * step
            qd[:, i] += ds / span * step
            qdd[:, i] += dds / span**2 * step
    legs = [ch.dof(j) for j in ("hip_r", "knee_r", "ankle_r")]
    root_x, root_z, root_pitch = ch.root_dofs
    for arr in (q, qd, qdd):
        arr[:, root_pitch] = -arr[:, legs].sum(axis=1)
    hip = ch.dof("hip_r")
    frac = np.divide(q[:, hip] - q0[hip], dq[hip]) if dq[hip] else np.zeros(n)
    for i in (root_x, root_z):
        q[:, i] = q0[i] + frac * dq[i]
        qd[:, i] = qdd[:, i] = 0.0
    return q, qd, qdd


def joint_windows(task: Task) -> dict[str, tuple[float, float]]:
    """Per-dof easing window as fractions of T (bare names expand to both sides)."""
    out = {}
    for key, win in task.timing.items():
        names = [f"{key}_r", f"{key}_l"] if key in SIDED_JOINTS else [key]
        for n in names:
            out[n] = win
    return out
