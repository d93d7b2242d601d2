"""One clip simulated and scored, as JSON-safe values: what ``cmrt simulate`` prints and scripts keep."""

from __future__ import annotations

import math
import time
from dataclasses import fields

import numpy as np

from cmrt import inputs
from cmrt.motion.curve import Cmrt
from cmrt.motion.sequence import SequenceTask
from cmrt.motion.task import Task
from cmrt.sim.objective import ENFORCE_TIMING, Evaluation, evaluate, verdict_bounds
from cmrt.sim.simulate import Trajectory, simulate


def _finite(x):
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else x


def evaluation_dict(ev: Evaluation) -> dict:
    """An Evaluation as JSON-safe values (non-finite floats become null), with the verdict's fixed bounds."""
    return {**{f.name: _finite(getattr(ev, f.name)) for f in fields(ev)}, "verdict_bounds": verdict_bounds()}


def dof_names(task: Task | SequenceTask) -> np.ndarray:
    """Names of a trace's qvel columns: the humanoid's dofs, then the prop's."""
    m = task.model()
    return np.array([m.joint(int(m.dof_jntid[i])).name for i in range(m.nv)])


def save_trace(path: str, task: Task | SequenceTask, traj: Trajectory, flag: str = "--trace") -> None:
    """Every recorded array of a clip and its dof names as ``.npz``, written atomically
    (``cmrt.inputs.atomic_output``): a failed write never leaves a half-written file."""
    with inputs.atomic_output(path, flag) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **traj.as_npz_dict(), dof_names=dof_names(task))


def simulate_report(task: Task, curve: Cmrt, curve_name: str, trace: str | None = None) -> dict:
    """Simulate one clip and score it: the task, the curve and every field of its Evaluation, with the wall
    time; ``trace``: also save the trajectory there (the path is checked before the simulation)."""
    if trace is not None:  # --trace '' is a bad path, not "no trace"
        inputs.check_output(trace, "--trace")  # before the simulation, not after it
    t0 = time.perf_counter()
    traj = simulate(task, curve)
    ev = evaluate(task, traj)
    wall = time.perf_counter() - t0
    if trace is not None:
        save_trace(trace, task, traj)
    return {
        "task": task.name,
        "speed": task.speed,
        "reference": task.reference_mode,
        "params": task.params,
        "curve": curve_name,
        "cmrt": curve.to_dict(),
        **evaluation_dict(ev),
        "timing_lag_enforced": ENFORCE_TIMING,  # whether success requires timing_lag_s <= its bound
        "wall_s": round(wall, 4),
    }


def sequence_report(seq: SequenceTask, curve: Cmrt, curve_name: str, trace: str | None = None) -> dict:
    """Simulate a sequence of motions and score it: what ``cmrt sequence`` prints (``trace``: also save the
    recorded trajectory there)."""
    if trace is not None:
        inputs.check_output(trace, "--trace")
    t0 = time.perf_counter()
    traj = simulate(seq, curve, record=trace is not None)
    ev = evaluate(seq, traj)
    if trace is not None:
        save_trace(trace, seq, traj)
    return {
        "sequence": seq.name,
        "curve": curve_name,
        "clip_s": seq.clip_s,
        "motions": [{"task": m.task.name, "speed": m.task.speed, "start_s": m.start_s} for m in seq.motions],
        **evaluation_dict(ev),
        "wall_s": round(time.perf_counter() - t0, 3),
    }
