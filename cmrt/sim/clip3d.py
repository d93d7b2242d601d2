"""A 3D task's clip and its score: what ``cmrt simulate``, the evaluators and the driver see of the 3D body.

A 3D task (``Task.body`` "humanoid3d", docs/body3d.md) stands, pushed or not (``cmrt.sim.spatial.stand_3d``), or
lifts a foot (``stance_side`` +-1: ``cmrt.sim.spatial.leg_lift_3d``): the weight shift over ``1 - lift_fraction``
of T from P, the lift over the rest, then the one-leg pose held to the clip's end. The CMRT acts sideways (y),
across the support's change, where the leg lift's anticipation is; the planar CMRT's 8 parameters and the same
driver. The verdict is the planar one's (the same rules, bounds and order, ``cmrt.sim.objective``) with the
leg lift's "performed" (the foot up within ``FOOT_LIFT_TOLERANCE_M`` of its height at the end and off the floor)
and "on_time" (the planar timing rule on the driving joints, ``objective.joint_lags_s``, bound 0.1 T and 0.05 s).
The objective is the paper's: the CoP error's 2-norm against the controller's own CoP reference, plus the planar
penalties' shapes (``cmrt.sim.spatial.cop_error_objective``, and ``NOT_PERFORMED_PENALTY`` for a motion not done or
late).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmrt.body.character import character
from cmrt.errors import CmrtError
from cmrt.motion.curve import Cmrt
from cmrt.motion.task import Task
from cmrt.sim.objective import NOT_PERFORMED_PENALTY, joint_lags_s, timing_lag_bound_s
from cmrt.sim.spatial import (
    LegLiftClip,
    StandResult,
    cop_error_objective,
    feet_centre_xy,
    leg_lift_3d,
    stand_3d,
    stand_pose_qpos,
)

LIFT_HEIGHT_M = 0.10  # the lifted foot's height in the one-leg pose (cmrt.body.one_leg)
FOOT_LIFT_TOLERANCE_M = 0.01  # performed: the foot ends within this of its height


@dataclass(frozen=True)
class Clip3d:
    """A 3D task's clip, its verdict and its objective."""

    result: StandResult
    objective: float
    failed_rules: tuple[str, ...]  # the planar verdict's rules, in its order; empty for a success
    lift: LegLiftClip | None = None  # a leg lift's own figures
    timing_lag_s: float | None = None
    timing_lag_bound_s: float | None = None

    @property
    def success(self) -> bool:
        return not self.failed_rules

    @property
    def fell(self) -> bool:
        return self.result.fell


def stance_index(task: Task) -> int:
    """The stood-on foot of a leg lift as the 3D body's index (0 right, 1 left)."""
    return 1 if task.params["stance_side"] > 0 else 0


def clip_3d(task: Task, curve: Cmrt) -> Clip3d:
    """Simulate and score a 3D task with ``curve`` (its CMRT in y; a standing task takes only the zero one)."""
    p = task.params
    push = (p["push_force_n"], p["push_force_y_n"], 0.0)
    if p["stance_side"] == 0 and any(curve.values_m):
        raise CmrtError("a standing 3D task takes no CMRT (docs/body3d.md): only the zero one")
    if p["stance_side"] == 0:
        r = stand_3d(clip_s=p["clip_s"], push_n=push, push_start_s=p["push_start_s"],
                     push_duration_s=p["push_duration_s"])
        centre = np.broadcast_to(feet_centre_xy(stand_pose_qpos()), r.cop_xy_m.shape)  # the CoP's reference
        return Clip3d(r, cop_error_objective(r, centre), r.failed_rules)
    lift_s = p["lift_fraction"] * p["duration_s"]
    lift = leg_lift_3d(shift_s=p["duration_s"] - lift_s, lift_s=lift_s, clip_s=p["clip_s"],
                       stance=stance_index(task), cmrt_y=curve, start_s=p["preparation_s"],
                       reference=task.reference_mode,
                       push=(push, p["push_start_s"], p["push_duration_s"]) if any(push) else None)
    r = lift.result
    lag, bound = _lag(task, lift), timing_lag_bound_s(task)
    done = abs(lift.foot_lift_m - LIFT_HEIGHT_M) <= FOOT_LIFT_TOLERANCE_M and not r.fell
    failed = list(r.failed_rules)
    at = 1 if "balance" in failed else 0  # the planar order: balance, performed, on_time, settled, ...
    late = lag is not None and lag > bound + 1e-12
    failed[at:at] = [rule for rule, broken in (("performed", not done and not r.fell), ("on_time", late)) if broken]
    value = cop_error_objective(r, lift.cop_reference_xy_m)
    if ("performed" in failed or "on_time" in failed) and not r.fell:
        excess = 1.0 if "performed" in failed else min(max((lag or 0.0) / bound - 1.0, 0.0), 1.0)
        value += NOT_PERFORMED_PENALTY * (1.0 + excess)
    return Clip3d(r, value, tuple(failed), lift, lag, bound)


def _lag(task: Task, lift: LegLiftClip) -> float | None:
    """The planar timing rule on the 3D body's actuated joints over [P, P + T] (None: it fell first)."""
    r, start = lift.result, task.preparation_s
    m = character(task.body).model
    keep = r.time_s >= start - 1e-9
    if r.fell:
        keep &= r.time_s < r.fall_time_s
    if not keep.any():
        return None
    t = r.time_s[keep]
    joints = [int(m.jnt_qposadr[j]) for j in m.actuator_trnid[:, 0]]
    lags = joint_lags_s(t, r.qpos[keep], lift.q_reference[keep], joints, t <= start + task.duration_s + 1e-9, start)
    return max(0.0, float(max(lags))) if lags else None
