"""One clip simulated and scored, as JSON-safe values: what ``cmrt simulate`` prints and scripts keep."""

from __future__ import annotations

import math
import time
from dataclasses import fields

import numpy as np

from cmrt import inputs
from cmrt.control.controller import ControllerConfig
from cmrt.motion.curve import Cmrt
from cmrt.motion.sequence import SequenceTask
from cmrt.motion.task import Task
from cmrt.sim import objective
from cmrt.sim import simulate as planar
from cmrt.sim.clip3d import Clip3d, clip_3d
from cmrt.sim.objective import ENFORCE_TIMING, Evaluation, verdict_bounds
from cmrt.sim.simulate import Trajectory


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


def simulate(task: Task, curve: Cmrt | None = None, config: ControllerConfig | None = None,
             record: bool = True) -> Trajectory | Clip3d:
    """Simulate one clip of ``task`` with CMRT ``curve`` (None: zero CMRT): a planar task's recorded trajectory
    (``cmrt.sim.simulate.simulate``), a 3D task's clip (``cmrt.sim.clip3d.clip_3d``, the default controller's);
    ``evaluate`` scores either. What ``cmrt.simulate`` is (``config``: the planar controller's, None its default)."""
    if getattr(task, "body", "planar") != "planar":
        return clip_3d(task, curve if curve is not None else Cmrt.zero(task.clip_s, task.cmrt_axes))
    if config is None:
        return planar.simulate(task, curve, record=record)
    return planar.simulate(task, curve, config, record)


def evaluate(task: Task, clip: Trajectory | Clip3d) -> Evaluation:
    """Score a clip ``simulate`` made: the planar scoring (``cmrt.sim.objective.evaluate``), or a 3D clip's
    verdict and objective as the same record. What ``cmrt.evaluate`` is."""
    if getattr(task, "body", "planar") != "planar":
        return clip.evaluation()
    return objective.evaluate(task, clip)


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


SPATIAL_RULES = {
    "standing": "standing (the 3D body): no fall (the capture point within 1 cm of the soles), still at the end, "
                "planned and executed CoP within 5 mm, the CoP inside the feet, ground force within 2.5 body weights, "
                "back in its pose within 0.1 rad",
    "pose change": "pose change (the 3D body): the end pose within 0.1 rad, tracked within its bound and on time "
                   "(the planar rules), no fall, still at the end, planned and executed CoP within 5 mm, the CoP "
                   "inside the feet, ground force within 2.5 body weights",
    "interaction": "interaction (the 3D body): the prop's goal met (the ball caught and held) and on time (the planar "
                   "rules), no fall, still at the end, planned and executed CoP within 5 mm outside the impact, the "
                   "CoP inside the feet, ground force within 2.5 body weights, the end pose within 0.1 rad",
    "leg lift": "leg lift (the 3D body): the foot 10 cm up within 1 cm at the end and on time (the planar timing "
                "rule), no fall, still at the end, planned and executed CoP within 5 mm, the CoP inside the stance "
                "foot, ground force within 2.5 body weights, the one-leg pose within 0.1 rad",
}


def spatial_report(task: Task, curve: Cmrt, curve_name: str, trace: str | None = None) -> dict:
    """A 3D task's clip (``cmrt.sim.clip3d``: standing, pushed or not, a leg lift or a pose change) and its verdict,
    as JSON-safe values; ``trace``: its samples as ``.npz``. A standing task's CMRT is the zero one."""
    t0 = time.perf_counter()
    c = clip_3d(task, curve)
    wall = time.perf_counter() - t0
    if trace is not None:
        _save_spatial_trace(trace, c)
    return spatial_dict(task, c, curve, curve_name) | {"wall_s": round(wall, 4)}


def _save_spatial_trace(path: str, c: Clip3d) -> None:
    """A 3D clip's samples as ``.npz`` (written whole or not at all)."""
    r = c.result
    with inputs.atomic_output(path, "--trace") as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, time_s=r.time_s, qpos=r.qpos, com_m=r.com_m, cop_xy_m=r.cop_xy_m,
                            plan_cop_xy_m=r.plan_cop_xy_m)


def spatial_dict(task: Task, c: Clip3d, curve: Cmrt, curve_name: str) -> dict:
    """A scored 3D clip as ``cmrt simulate --json`` prints it (JSON-safe values; without the wall time)."""
    r = c.result
    figures = ("fell", "fall_time_s", "max_plan_cop_error_m", "min_cop_margin_m", "peak_normal_force_bw",
               "airborne_s", "max_joint_speed_rad_s", "max_foot_slip_m", "final_com_speed_m_s", "infeasible_steps")
    out = {
        "task": task.name, "body": task.body, "speed": task.speed, "reference": task.reference_mode,
        "params": task.params, "curve": curve_name, "cmrt": curve.to_dict(), "objective": c.objective,
        "success": c.success, "failed_rules": list(c.failed_rules),
        "success_rule": SPATIAL_RULES[c.kind], "final_pose_error_rad": _finite(c.final_pose_error_rad),
        **{k: _finite(getattr(r, k)) for k in figures},
        "fall_direction_xy": None if r.fall_direction_xy is None else [float(v) for v in r.fall_direction_xy],
        "topple_direction_xy": None if r.topple_direction_xy is None else [float(v) for v in r.topple_direction_xy],
    }
    if c.lift is not None:
        out |= {"lift_off_s": c.lift.lift_off_s, "foot_lift_m": c.lift.foot_lift_m,
                "com_shift_toward_stance_before_lift_off_m": c.lift.com_shift_m,
                "timing_lag_s": c.timing_lag_s, "timing_lag_bound_s": c.timing_lag_bound_s}
    if c.kind in ("pose change", "interaction"):
        out |= {"tracking_error_rad": c.tracking_error_rad, "tracking_bound_rad": c.tracking_bound_rad,
                "timing_lag_s": c.timing_lag_s,
                "timing_lag_bound_s": c.timing_lag_bound_s}
    out |= c.prop_figures()
    return out | {"verdict_bounds": verdict_bounds()}


def sequence_report(seq: SequenceTask, curve: Cmrt, curve_name: str, trace: str | None = None) -> dict:
    """Simulate a sequence of motions and score it: what ``cmrt sequence`` prints (``trace``: also save the
    recorded trajectory there)."""
    if trace is not None:
        inputs.check_output(trace, "--trace")
    t0 = time.perf_counter()
    traj = simulate(seq, curve, record=trace is not None)  # a 3D sequence's: its clip (cmrt.sim.clip3d)
    ev = evaluate(seq, traj)
    if trace is not None and isinstance(traj, Clip3d):
        _save_spatial_trace(trace, traj)
    elif trace is not None:
        save_trace(trace, seq, traj)
    return {
        "sequence": seq.name,
        "curve": curve_name,
        "clip_s": seq.clip_s,
        "motions": [{"task": m.task.name, "speed": m.task.speed, "start_s": m.start_s} for m in seq.motions],
        **evaluation_dict(ev),
        "wall_s": round(time.perf_counter() - t0, 3),
    }
