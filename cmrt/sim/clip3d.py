"""A 3D task's clip and its score: what ``cmrt simulate``, the evaluators and the driver see of the 3D body.

A 3D task (``Task.body`` "humanoid3d", docs/body3d.md) stands, pushed or not (``cmrt.sim.spatial.stand_3d``), lifts
a foot (``stance_side`` +-1: ``cmrt.sim.spatial.leg_lift_3d``: the weight shift over ``1 - lift_fraction`` of T from
P, the lift over the rest, then the one-leg pose held to the clip's end), or changes its pose sagittally (an end
pose: the planar reference on the 3D body, ``cmrt.sim.spatial.pose_change_3d``), catching a ball as it does (an
interaction: the planar prop, ``cmrt.sim.prop3d``). A leg lift's CMRT acts sideways (y), across the support's
change, where its anticipation is; a pose change's forward (x), as on the planar body; the planar CMRT's 8
parameters and the same driver. The verdict is the planar one's (the same rules, bounds and order,
``cmrt.sim.objective``): "performed" (a leg lift's foot up within ``FOOT_LIFT_TOLERANCE_M`` of its height at the
end; a pose change's end pose and tracking bound; an interaction's prop goal), "on_time" (the planar timing rule on
the driving joints, ``objective.joint_lags_s``, bound 0.1 T and 0.05 s), the standing rules, and "final_pose" where
"performed" does not judge the end pose. The objective is the paper's: the CoP error's 2-norm against the
controller's own CoP reference, plus the planar penalties' shapes (``cmrt.sim.spatial.cop_error_objective``;
``NOT_PERFORMED_PENALTY`` for a motion not done or late; ``MISSED_GOAL_PENALTY`` for a missed goal;
``NOT_PLAUSIBLE_PENALTY`` for the end pose).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import mujoco
import numpy as np

from cmrt.body.character import character
from cmrt.body.props import CONTACT_FORCE_N, prop_class
from cmrt.body.sagittal import planar_to_3d
from cmrt.errors import CmrtError
from cmrt.motion.curve import Cmrt
from cmrt.motion.ensemble import Perturbation
from cmrt.motion.task import Task
from cmrt.sim.objective import (
    FINAL_POSE_TOLERANCE_RAD,
    MISSED_GOAL_PENALTY,
    NOT_PERFORMED_PENALTY,
    NOT_PLAUSIBLE_PENALTY,
    Evaluation,
    contact_summary,
    motion_lags,
    reachable,
    timing_lag_bound_s,
)
from cmrt.sim.prop3d import HeldProp, force_times_s
from cmrt.sim.spatial import (
    LegLiftClip,
    StandResult,
    cop_error_objective,
    feet_centre_xy,
    leg_lift_3d,
    pose_change_3d,
    stand_3d,
    stand_pose_qpos,
)

EVALUATION_FIELDS = frozenset(f.name for f in fields(Evaluation))
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
    tracking_error_rad: float | None = None  # a pose change's: RMS over [P, P + T] and its bound (None: it fell
    tracking_bound_rad: float | None = None  # before P, or not a pose change)
    final_pose_error_rad: float = 0.0  # the actuated joints' distance from the reference's last pose at the end
    cop_reference_xy_m: np.ndarray | None = None  # (n, 2) the CoP's reference the objective measured against
    kind: str = "standing"  # "standing", "leg lift", "pose change" or "interaction" (a pose change with a prop)

    @property
    def success(self) -> bool:
        return not self.failed_rules

    def prop_figures(self) -> dict:
        """A held prop's figures as the planar clip's (``Evaluation``'s names; empty without a prop): its goal
        (``task_success``), the hands' first contact, peak force and impulse before any fall, the prop's own."""
        r = self.result
        if r.prop_force_n is None:
            return {}
        times = force_times_s(r.prop_force_n.size, character("humanoid3d").model.opt.timestep)
        before = times < r.fall_time_s if r.fall_time_s is not None else np.ones(times.size, bool)
        return {"task_success": r.prop_goal, **contact_summary(r.prop_force_n, times, before),
                **{k: (v if np.isfinite(v) else None) for k, v in r.prop_extras}}

    def evaluation(self) -> Evaluation:
        """The clip as the planar scoring's record (``cmrt.evaluate``: the fields of ``cmrt simulate --json`` that
        a 3D clip has; the planar-only ones - steps, after-fall figures - empty)."""
        r = self.result
        err = np.nan_to_num(r.cop_xy_m - self.cop_reference_xy_m, nan=0.3)
        dt = float(r.time_s[1] - r.time_s[0]) if len(r.time_s) > 1 else 0.01
        norm = float(np.linalg.norm(err)) * np.sqrt(dt / 0.01)  # as cop_error_objective samples it
        moving = self.kind != "standing"
        return Evaluation(
            objective=self.objective, cop_error_norm=norm, penalty=self.objective - norm,
            cop_error_own_reference_norm=norm, success=self.success,
            performed=(not {"performed", "on_time"} & set(self.failed_rules) and not r.fell) if moving else None,
            settled="settled" not in self.failed_rules and not r.fell, fell=r.fell, fall_time_s=r.fall_time_s,
            fall_reason="capture point" if r.fell else None, diverged=False,
            max_cop_error_m=float(np.linalg.norm(err, axis=1).max()) if len(err) else 0.0,
            min_cop_margin_m=r.min_cop_margin_m, peak_normal_force_bw=r.peak_normal_force_bw,
            airborne_s=r.airborne_s, max_joint_speed_rad_s=r.max_joint_speed_rad_s,
            tracking_error_rad=self.tracking_error_rad, tracking_bound_rad=self.tracking_bound_rad,
            final_pose_error_rad=self.final_pose_error_rad, final_com_speed_m_s=r.final_com_speed_m_s,
            n_samples=len(r.time_s), max_plan_cop_error_m=r.max_plan_cop_error_m,
            max_foot_slip_m=r.max_foot_slip_m, timing_lag_s=self.timing_lag_s,
            timing_lag_bound_s=self.timing_lag_bound_s if moving else None, failed_rules=self.failed_rules,
            **{k: v for k, v in self.prop_figures().items() if k in EVALUATION_FIELDS})

    @property
    def fell(self) -> bool:
        return self.result.fell


def stance_index(task: Task) -> int:
    """The stood-on foot of a leg lift as the 3D body's index (0 right, 1 left)."""
    return 1 if task.params["stance_side"] > 0 else 0


def perturbed_3d(task: Task, member: Perturbation) -> Task:
    """The 3D task as an ensemble member plays it (``cmrt.motion.ensemble``): its motion's timing scaled, and its
    thorax push along the axis the CMRT acts in - sideways (+y, to the left) for a leg lift, forward for a pose
    change - where the planar members push forward. A task that pushes of its own takes no member's push (one push
    window per clip)."""
    task = member.task_variant(task)
    if member.push_force_n == 0.0:
        return task
    if task.params["push_force_n"] or task.params["push_force_y_n"]:
        raise CmrtError("a 3D task that pushes of its own has no robust ensemble (one push per clip)")
    axis = "push_force_n" if task.end_pose_deg is not None else "push_force_y_n"
    return replace(task, params={**task.params, axis: member.push_force_n, "push_start_s": member.push_start_s,
                                 "push_duration_s": member.push_duration_s})


def clip_3d(task: Task, curve: Cmrt, member: Perturbation | None = None) -> Clip3d:
    """Simulate and score a 3D task with ``curve`` (a leg lift's CMRT in y, a pose change's in x, and a two-axis
    CMRT's cross values in the other; a standing task takes only the zero one); ``member``: as that ensemble
    member plays it (``perturbed_3d``)."""
    if member is not None:
        task = perturbed_3d(task, member)
    p = task.params
    push = (p["push_force_n"], p["push_force_y_n"], 0.0)
    pushed = (push, p["push_start_s"], p["push_duration_s"]) if any(push) else None
    if task.end_pose_deg is not None:
        return _pose_change(task, curve, pushed, 1.0 if member is None else member.prop_mass_scale)
    if p["stance_side"] == 0 and (any(curve.values_m) or any(curve.cross_values_m or ())):
        raise CmrtError("a standing 3D task takes no CMRT (docs/body3d.md): only the zero one")
    if p["stance_side"] == 0:
        start = stand_pose_qpos()
        r = stand_3d(clip_s=p["clip_s"], push_n=push, push_start_s=p["push_start_s"],
                     push_duration_s=p["push_duration_s"], start_qpos=start)
        centre = np.broadcast_to(feet_centre_xy(start), r.cop_xy_m.shape)  # the CoP's reference
        final = _final_pose_error(task, r, start)
        failed, value = _judged(task, r, True, 0.0, (None, None), centre, final)
        return Clip3d(r, value, failed, final_pose_error_rad=final, cop_reference_xy_m=centre)
    lift_s = p["lift_fraction"] * p["duration_s"]
    lift = leg_lift_3d(shift_s=p["duration_s"] - lift_s, lift_s=lift_s, clip_s=p["clip_s"],
                       stance=stance_index(task), cmrt_y=curve.along(), start_s=p["preparation_s"],
                       reference=task.reference_mode, push=pushed, cmrt_x=_cross(curve))
    r = lift.result
    lag, lag_bound = _lag(task, r, lift.q_reference)
    done = abs(lift.foot_lift_m - LIFT_HEIGHT_M) <= FOOT_LIFT_TOLERANCE_M and not r.fell
    final = _final_pose_error(task, r, lift.q_reference[-1])
    failed, value = _judged(task, r, done, 1.0, (lag, lag_bound), lift.cop_reference_xy_m, final)
    return Clip3d(r, value, failed, lift, lag, lag_bound, final_pose_error_rad=final,
                  cop_reference_xy_m=lift.cop_reference_xy_m, kind="leg lift")


def _pose_change(task: Task, curve: Cmrt, push, prop_mass_scale: float = 1.0) -> Clip3d:
    """A planar task's pose change played by the 3D body (``cmrt.body.sagittal``), its CMRT forward: performed
    as the planar rule says - the end pose within 0.1 rad (the actuated joints' distance) and the motion tracked
    over [P, P + T] within the RMS of its own reference played ``max_tracking_lag`` x T late - and on time; with a
    prop, its goal met instead (``prop_mass_scale``: an ensemble member's prop mass, as a multiple of the task's)."""
    if task.reference_mode != "center":
        raise CmrtError(f"a 3D pose change takes the centre reference for now, not {task.reference_mode}")
    start = stand_pose_qpos(task.start_pose_deg)

    def reference(t: np.ndarray):
        return planar_to_3d(*task.reference(t), start)

    held = None
    if task.prop is not None:  # a ball to catch (cmrt.sim.prop3d): the planar prop on the 3D body
        end = stand_pose_qpos(task.end_pose_deg)
        held = HeldProp(task.prop, dict(task.params), task.model(), end, task.task_window_s(), prop_mass_scale)
    r, q_ref = pose_change_3d(reference, start, task.clip_s, curve.along(), push=push, held=held,
                              cmrt_y=_cross(curve))
    m = character(task.body).model
    act = m.jnt_qposadr[m.actuator_trnid[:, 0]]
    final = _final_pose_error(task, r, q_ref[-1])
    lo, hi = task.task_window_s()
    window = (r.time_s >= lo - 1e-9) & (r.time_s <= hi + 1e-9)
    if r.fell:
        window &= r.time_s < r.fall_time_s
    tracking = bound = None  # None: it fell before the motion began
    if window.any():
        tracking = float(np.sqrt(np.mean((r.qpos[window][:, act] - q_ref[window][:, act]) ** 2)))
        late_ref = reference(r.time_s[window] - task.params["max_tracking_lag"] * task.duration_s)[0]
        bound = float(np.sqrt(np.mean((late_ref[:, act] - q_ref[window][:, act]) ** 2)))
    done = tracking is not None and final < FINAL_POSE_TOLERANCE_RAD and tracking <= bound and not r.fell
    lag, lag_bound = _lag(task, r, q_ref)
    centre = np.broadcast_to(feet_centre_xy(start), r.cop_xy_m.shape)
    miss = tracking / bound - 1.0 if tracking is not None and bound > 0 else 1.0
    if held is not None:  # the planar interaction's rule: performed is the goal met, the end pose a rule of its own
        failed, value = _judged(task, r, bool(r.prop_goal) and not r.fell, 1.0, (lag, lag_bound), centre, final,
                                r.prop_goal)
        return Clip3d(r, value, failed, None, lag, lag_bound, tracking, bound, final, centre,
                      "interaction")
    failed, value = _judged(task, r, done, miss, (lag, lag_bound), centre, None)
    return Clip3d(r, value, failed, None, lag, lag_bound, tracking, bound, final, centre,
                  "pose change")


def _cross(curve: Cmrt) -> Cmrt | None:
    """A two-axis CMRT's displacement across the task's axis (None for a one-axis CMRT: its clip as before)."""
    return curve.cross if curve.axes == 2 else None


def _final_pose_error(task: Task, r: StandResult, target: np.ndarray) -> float:
    """The actuated joints' distance (rad) at the clip's end from ``target`` (a qpos): the planar final pose
    error."""
    m = character(task.body).model
    act = m.jnt_qposadr[m.actuator_trnid[:, 0]]
    return float(np.linalg.norm(r.qpos[-1, act] - target[act]))


def _judged(task: Task, r: StandResult, done: bool, miss: float, timing: tuple[float | None, float | None],
            cop_reference: np.ndarray, final: float | None, goal: bool | None = None) -> tuple[tuple[str, ...], float]:
    """The planar verdict's order (balance, performed, on_time, then the clip's own rules, final_pose last) and
    the paper's objective with the planar penalties: ``miss`` is how far a motion not done was off (its excess over
    the tracking bound; 1 where it is not measured), ``timing`` how late it was and how late it may be
    (``_lag``), ``final`` the end pose's error where
    a rule of its own judges it (None where "performed" does: a pose change), ``goal`` a prop's goal (None: no
    prop; missed, the planar ``MISSED_GOAL_PENALTY``, fallen or not, in place of the motion's)."""
    lag, bound = timing
    failed = list(r.failed_rules)
    at = 1 if "balance" in failed else 0
    late = lag is not None and lag > bound + 1e-12
    failed[at:at] = [rule for rule, broken in (("performed", not done and not r.fell), ("on_time", late)) if broken]
    value = cop_error_objective(r, cop_reference)
    if final is not None and not r.fell and final >= FINAL_POSE_TOLERANCE_RAD:
        failed.append("final_pose")
        if not r.failed_rules:  # cop_error_objective added no plausibility penalty for it
            value += NOT_PLAUSIBLE_PENALTY * (1.0 + min(final / FINAL_POSE_TOLERANCE_RAD - 1.0, 1.0))
    if goal is False:
        value += MISSED_GOAL_PENALTY
    elif ("performed" in failed or "on_time" in failed) and not r.fell:
        excess = miss if "performed" in failed else 0.0
        if late:
            excess = max(excess, lag / bound - 1.0)
        value += NOT_PERFORMED_PENALTY * (1.0 + min(max(excess, 0.0), 1.0))
    return tuple(failed), value


def _lag(task: Task, r: StandResult, q_reference: np.ndarray) -> tuple[float | None, float]:
    """How late the motion was and how late it may be: the planar timing rule on the 3D body's actuated joints over
    [P, P + T] - a sequence's each motion over its own window, against its own bound (``objective.timed_motions``)
    -, the task's balance joint (its pitch and roll) excepted as on the planar body, against the reference kept
    inside the stops as the controller keeps it (``objective.reachable``) (lag None: it fell first); a struck
    prop's first touch inside the window stops the limb that hits it, as on the planar body
    (``objective.joint_lags_s``'s ``strike_s``)."""
    m = character(task.body).model
    skip = task.balance_joint if task.end_pose_deg is not None else None
    joints = [int(m.jnt_qposadr[j]) for j in m.actuator_trnid[:, 0]
              if not (skip and m.joint(int(j)).name.split("_")[0] == skip)]
    alive = r.time_s < r.fall_time_s if r.fell else np.ones(r.time_s.size, bool)
    q_ref, strike_s = reachable(q_reference, task.body)[alive], _strike_s(task, r)
    lag, bound = motion_lags(task, r.time_s[alive], r.qpos[alive], lambda keep: q_ref[keep], joints,
                             lambda start, stop: strike_s)
    return lag, bound if bound is not None else timing_lag_bound_s(task)


def _strike_s(task: Task, r: StandResult) -> float | None:
    """The hands' first touch of a struck prop (a bag) inside the task window (None: not a strike)."""
    if r.prop_force_n is None or not prop_class(task.prop).struck:
        return None
    times = force_times_s(r.prop_force_n.size, character(task.body).model.opt.timestep)
    start, stop = task.task_window_s()
    hit = np.flatnonzero((r.prop_force_n > CONTACT_FORCE_N) & (times >= start - 1e-9) & (times <= stop + 1e-9))
    return float(times[hit[0]]) if hit.size else None


def cop_trace(task: Task, c: Clip3d, axis: int = 1) -> dict[str, np.ndarray]:
    """The clip's CoP error along ``axis`` (0 forward, x; 1 sideways, y) from the controller's CoP reference and
    the support's edges along it about that reference (the foot points the verdict's support polygon is made of:
    both feet's until lift-off, the stance foot's after), up to a fall: what a 3D run's CoP plot shows (m)."""
    r = c.result
    ch = character(task.body)
    both = r.qpos[0, :ch.model.nq]  # the body's coordinates (a prop's follow them)
    d = mujoco.MjData(ch.model)
    d.qpos[:] = both
    mujoco.mj_kinematics(ch.model, d)
    feet = [d.geom_xpos[list(pair), axis] for pair in ch.foot_points]
    reference = c.lift.cop_reference_xy_m if c.lift is not None else np.broadcast_to(
        feet_centre_xy(both), r.cop_xy_m.shape)
    lifted = (r.time_s >= c.lift.lift_off_s) if c.lift is not None else np.zeros(r.time_s.size, bool)
    stance = feet[stance_index(task)] if c.lift is not None else np.concatenate(feet)
    every = np.concatenate(feet)
    lo = np.where(lifted, stance.min(), every.min()) - reference[:, axis]
    hi = np.where(lifted, stance.max(), every.max()) - reference[:, axis]
    n = r.time_s.size if r.fall_time_s is None else int(np.searchsorted(r.time_s, r.fall_time_s, "right"))
    return {"time_s": r.time_s[:n], "cop_error_m": (r.cop_xy_m[:, axis] - reference[:, axis])[:n],
            "support_lo_m": lo[:n], "support_hi_m": hi[:n]}


def cmrt_axis(task: Task) -> int:
    """The horizontal axis a 3D task's CMRT acts in first: 1 (sideways, y) for a leg lift, 0 (forward, x) for a
    pose change - its CoP plot's axis."""
    return 0 if task.end_pose_deg is not None else 1
