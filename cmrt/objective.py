"""Trajectory -> scalar objective (ABC section 4.1), with penalties for balance loss.

objective = |e|_2 + penalty, where e(t_k) = p(t_k) - s(t_k) is the measured CoP minus
the support centre (metres), sampled every ``cop_sample_step_s`` of the task (the 2-norm
grows with the sample count, so the step is fixed per task, not tied to the physics
step). Samples where the feet carry less than ``MIN_FOOT_FORCE_FRACTION`` of body weight
are dropped: the CoP is ill-defined there.

Penalty (0 when balance is kept). A flat "fell" penalty gives CMA-ES no slope, so it is
graded by how early balance was lost and how far the foot lifted:

    fell:     FALL_PENALTY + 10 (L - t_fail) / L + 50 min(max_lift - 0.01 m, 0.2 m)
    blow-up:  DIVERGED_PENALTY (worse than any fall)
    goal missed (tasks with a prop: ball not caught and held, slab not toppled, target
    not hit): + MISSED_GOAL_PENALTY, so that "do nothing and stay balanced" never wins
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmrt.character import character
from cmrt.control.controller import GRAVITY_M_S2
from cmrt.simulate import LIFT_STOP_M, LIFT_THRESHOLD_M, Trajectory
from cmrt.task import Task

MIN_FOOT_FORCE_FRACTION = 0.05
FALL_PENALTY = 10.0
DIVERGED_PENALTY = 100.0
MISSED_GOAL_PENALTY = 30.0  # ABC 5: a missed catch is heavily penalised (also: slab not toppled, no hit)


@dataclass(frozen=True)
class Evaluation:
    """What one clip scored; the fields of ``cmrt simulate --json``."""

    objective: float
    cop_error_norm: float
    penalty: float
    fell: bool
    fall_time_s: float | None
    fall_reason: str | None
    diverged: bool
    max_cop_error_m: float
    final_pose_error_rad: float
    n_samples: int
    task_success: bool | None = None


def cop_error_samples(task: Task, traj: Trajectory) -> np.ndarray:
    """e(t_k) at the task's sample step; NaN-free (dropped samples removed)."""
    dt = float(traj.time_s[1] - traj.time_s[0]) if traj.time_s.size > 1 else 1.0
    every = max(1, int(round(task.cop_sample_step_s / dt)))
    idx = np.arange(0, traj.time_s.size, every)
    weight = character().mass_kg * GRAVITY_M_S2
    loaded = traj.normal_force_n[idx] > MIN_FOOT_FORCE_FRACTION * weight
    e = traj.cop_x_m[idx] - traj.support_center_x_m[idx]
    keep = loaded & np.isfinite(e)
    return e[keep]


def evaluate(task: Task, traj: Trajectory) -> Evaluation:
    e = cop_error_samples(task, traj)
    norm = float(np.linalg.norm(e))
    if traj.diverged:
        penalty = DIVERGED_PENALTY
    elif traj.fell:
        t_fail = traj.fall_time_s if traj.fall_time_s is not None else 0.0
        lift = min(max(traj.max_lift_m - LIFT_THRESHOLD_M, 0.0), LIFT_STOP_M - LIFT_THRESHOLD_M)
        penalty = FALL_PENALTY + 10.0 * (task.clip_s - t_fail) / task.clip_s + 50.0 * lift
    else:
        penalty = 0.0
    if traj.task_success is False:
        penalty += MISSED_GOAL_PENALTY
    final_err = task.final_pose_error_rad(traj.final_qpos) if np.all(np.isfinite(traj.final_qpos)) else float("inf")
    return Evaluation(
        objective=norm + penalty,
        cop_error_norm=norm,
        penalty=penalty,
        fell=traj.fell,
        fall_time_s=traj.fall_time_s,
        fall_reason=traj.fall_reason,
        diverged=traj.diverged,
        max_cop_error_m=float(np.max(np.abs(e))) if e.size else 0.0,
        final_pose_error_rad=final_err,
        n_samples=int(e.size),
        task_success=traj.task_success,
    )
