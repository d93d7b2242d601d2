"""The reference motion of a task: each joint eased from pose to pose over the task phase [P, P + T].

It is computed from a :class:`Schedule` - the poses and timing a task's reference depends on, nothing else
(``Task.schedule()`` makes one) - so this module knows no Task. ``Task.reference``, ``Task.keyframes`` and
``Task.joint_windows`` are these functions on the task's schedule.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from cmrt.body.character import SIDED_JOINTS, character


@dataclass(frozen=True, eq=False)
class Schedule:
    """What a task's reference motion is made of: its poses as qpos (read-only arrays) and their timing."""

    key: str  # the task's content hash: two schedules with the same key are the same (the cache's key)
    start_qpos: np.ndarray
    end_qpos: np.ndarray | None  # None: no pose change, the start pose is held
    via_qpos: np.ndarray | None  # a pose passed through at ``via_fraction`` of T, or None
    via_fraction: float | None
    timing: dict[str, tuple[float, float]]  # ``[timing]``: per joint, its easing window as fractions of T
    preparation_s: float  # P
    duration_s: float  # T

    def __post_init__(self) -> None:
        for q in (self.start_qpos, self.end_qpos, self.via_qpos):
            if q is not None:
                q.flags.writeable = False


def smoothstep5(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quintic ease-in-ease-out on [0, 1]: value, d/ds, d2/ds2 (zero rate and acceleration at both ends)."""
    s = np.clip(s, 0.0, 1.0)
    return (
        s**3 * (10 - 15 * s + 6 * s**2),
        30 * s**2 * (1 - s) ** 2,
        60 * s * (1 - s) * (1 - 2 * s),
    )


def keyframes(schedule: Schedule) -> list[tuple[float, np.ndarray]]:
    """(fraction of T, qpos) of the poses the motion passes: start, [via], end (read-only arrays)."""
    keys = [(0.0, schedule.start_qpos)]
    if schedule.via_qpos is not None:
        keys.append((schedule.via_fraction, schedule.via_qpos))
    end = schedule.start_qpos if schedule.end_qpos is None else schedule.end_qpos
    return keys + [(1.0, end)]


_CACHE: OrderedDict[tuple[str, bytes], tuple[np.ndarray, np.ndarray, np.ndarray]] = OrderedDict()
_CACHE_SIZE = 64  # (task, times) pairs: a clip's steps, its scored samples, their late copies, ensemble timings
_CACHE_LOCK = threading.Lock()  # simulate_batch's threads ask for it at once


def reference(schedule: Schedule, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``reference_motion``, remembered per task and times (read-only arrays): every evaluation asks for
    the same clip's reference four times (the controller's, and the objective's tracking error and
    bound), and computing it cost ~15 % of an evaluation's physics."""
    t = np.atleast_1d(np.asarray(t_s, dtype=float))
    key = (schedule.key, t.tobytes())
    with _CACHE_LOCK:
        hit = _CACHE.get(key)
        if hit is not None:
            _CACHE.move_to_end(key)
            return hit
    out = reference_motion(schedule, t)
    for a in out:
        a.flags.writeable = False
    with _CACHE_LOCK:
        _CACHE[key] = out
        while len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
    return out


def reference_motion(schedule: Schedule, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference q, qd, qdd at times ``t_s`` (shape (n, nv)).

    Each joint eases from the start to the end pose (through the via pose, if any, at
    ``via_fraction`` of T) over its window of the task phase [P, P + T] (``[timing]``:
    fractions of T, default [0, 1]). The root pitch that keeps the right foot flat,
    -(hip + knee + ankle), follows the leg joints. The root's x and z are not tracked;
    they ease with the hip for completeness.
    """
    t = np.atleast_1d(np.asarray(t_s, dtype=float))
    q0, q1 = schedule.start_qpos, schedule.end_qpos
    n, nv = len(t), q0.size
    q, qd, qdd = np.tile(q0, (n, 1)), np.zeros((n, nv)), np.zeros((n, nv))
    if q1 is None:
        return q, qd, qdd
    ch = character()
    dq = q1 - q0
    windows = joint_windows(schedule)
    keys = keyframes(schedule)
    for (fa, qa), (fb, qb) in zip(keys, keys[1:], strict=False):
        for i, name in enumerate(ch.dof_names):
            a, b = windows.get(name, (0.0, 1.0)) if len(keys) == 2 else (fa, fb)
            span = (b - a) * schedule.duration_s
            s, ds, dds = smoothstep5((t - schedule.preparation_s - a * schedule.duration_s) / span)
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


def joint_windows(schedule: Schedule) -> dict[str, tuple[float, float]]:
    """Per-dof easing window as fractions of T (bare names expand to both sides)."""
    out = {}
    for key, win in schedule.timing.items():
        names = [f"{key}_r", f"{key}_l"] if key in SIDED_JOINTS else [key]
        for n in names:
            out[n] = win
    return out
