"""One clip simulated and scored, as JSON-safe values: what ``cmrt simulate`` prints and scripts keep."""

from __future__ import annotations

import math
import time
from dataclasses import fields

import numpy as np

from cmrt import inputs
from cmrt.errors import CmrtError
from cmrt.motion.curve import Cmrt
from cmrt.motion.sequence import SequenceTask
from cmrt.motion.task import Task
from cmrt.motion.taskfile import PARAMS_3D, params_off_3d
from cmrt.sim.objective import ENFORCE_TIMING, Evaluation, evaluate, verdict_bounds
from cmrt.sim.simulate import Trajectory, simulate
from cmrt.sim.spatial import stand_3d


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
    time; ``trace``: also save the trajectory there (the path is checked before the simulation). A 3D task's
    clip is ``cmrt.sim.spatial``'s (``spatial_report``)."""
    if trace is not None:  # --trace '' is a bad path, not "no trace"
        inputs.check_output(trace, "--trace")  # before the simulation, not after it
    if task.body != "planar":
        return spatial_report(task, curve, curve_name, trace)
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


SPATIAL_RULE = ("standing (the 3D body): no fall (the capture point within 1 cm of the soles), still at the end, "
                "planned and executed CoP within 5 mm, the CoP inside the feet, ground force within 2.5 body weights")


def spatial_report(task: Task, curve: Cmrt, curve_name: str, trace: str | None = None) -> dict:
    """A 3D task's clip (``cmrt.sim.spatial.stand_3d``: standing, pushed at the thorax) and its verdict, as
    JSON-safe values; ``trace``: its samples as ``.npz``. No CMRT yet (docs/body3d.md): only the zero one."""
    if any(curve.values_m):
        raise CmrtError(f"--curve {curve_name}: the 3D body has no CMRTs yet (docs/body3d.md); use --curve zero")
    fixed = params_off_3d(task.params)
    if fixed:
        raise CmrtError(f"--set {', '.join(sorted(fixed))}: not for the {task.body} body yet (it takes "
                        f"{', '.join(sorted(PARAMS_3D))})")
    p = task.params
    t0 = time.perf_counter()
    r = stand_3d(clip_s=p["clip_s"], push_n=(p["push_force_n"], p.get("push_force_y_n", 0.0), 0.0),
                 push_start_s=p["push_start_s"], push_duration_s=p["push_duration_s"])
    wall = time.perf_counter() - t0
    if trace is not None:
        with inputs.atomic_output(trace, "--trace") as tmp, open(tmp, "wb") as fh:
            np.savez_compressed(fh, time_s=r.time_s, qpos=r.qpos, com_m=r.com_m, cop_xy_m=r.cop_xy_m,
                                plan_cop_xy_m=r.plan_cop_xy_m)
    figures = ("fell", "fall_time_s", "max_plan_cop_error_m", "min_cop_margin_m", "peak_normal_force_bw",
               "airborne_s", "max_joint_speed_rad_s", "max_foot_slip_m", "final_com_speed_m_s", "infeasible_steps")
    return {
        "task": task.name, "body": task.body, "speed": None, "reference": task.reference_mode,
        "params": task.params, "curve": curve_name, "success": r.success, "failed_rules": list(r.failed_rules),
        "success_rule": SPATIAL_RULE, **{k: _finite(getattr(r, k)) for k in figures},
        "fall_direction_xy": None if r.fall_direction_xy is None else [float(v) for v in r.fall_direction_xy],
        "topple_direction_xy": None if r.topple_direction_xy is None else [float(v) for v in r.topple_direction_xy],
        "verdict_bounds": verdict_bounds(), "wall_s": round(wall, 4),
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
