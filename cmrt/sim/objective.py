"""Trajectory -> scalar objective (ABC section 4.1), penalties, and what a success is.

objective = |e|_2 + penalty, where e(t_k) = p(t_k) - s(t_k) is the measured CoP minus
the support centre (metres), sampled every ``cop_sample_step_s`` of the task over the
clip [0, L) and before any fall (the 2-norm grows with the sample count, so the step is
fixed per task, not tied to the physics step). Samples where the feet carry less than
``MIN_FOOT_FORCE_FRACTION`` of body weight are dropped: the CoP is ill-defined there.

A clip is a **success** when

* balance held over the clip and its standing tail (no fall, ``cmrt.sim.balance``);
* the motion was **performed**: a pose change ends within ``FINAL_POSE_TOLERANCE_RAD``
  of its target pose (at the end of the tail), tracked it during the task window
  [P, P + T] with an RMS joint error no larger than that of its own reference played
  ``max_tracking_lag`` x T late (0.1 of T by default; ~0.1 rad on the bend): a motion done late
  or half-heartedly is not the motion asked for (how late each driving joint arrived is reported as
  ``timing_lag_s``; with ``ENFORCE_TIMING`` it must be within ``timing_lag_bound_s``); a task with a
  prop met its goal (ball caught and held, slab toppled, pad struck); pure standing has
  nothing to perform (``performed`` is None);
* the character **settled**: at the end of the tail its CoM moves slower than
  ``SETTLED_COM_SPEED_M_S``.

Penalty (0 for a success), graded so that CMA-ES has a slope:

    fell:            FALL_PENALTY + 10 (L + tail - t_fall) / (L + tail)
    blow-up:         DIVERGED_PENALTY (worse than any fall)
    not performed:   NOT_PERFORMED_PENALTY * (1 + min(tracking error / its bound - 1, 1)) for a pose change
                     (with ``ENFORCE_TIMING``: the worse of that and lag / its bound);
                     MISSED_GOAL_PENALTY when a prop task's goal was missed (so that
                     "do nothing and stay balanced" never wins)
    not settled:     NOT_SETTLED_PENALTY
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import mujoco
import numpy as np

from cmrt.body.character import GRAVITY_M_S2, character
from cmrt.body.props import CONTACT_FORCE_N, prop_class
from cmrt.control.controller import ControllerConfig
from cmrt.motion.task import Task
from cmrt.sim.simulate import PLANTED_FORCE_N, Trajectory

MIN_FOOT_FORCE_FRACTION = 0.05
IMPACT_WINDOW_S = 0.1  # peak ground force is reported outside this window after the first hand-prop contact
AIRBORNE_FORCE_FRACTION = 0.01  # total foot normal force below this fraction of body weight: airborne
FINAL_POSE_TOLERANCE_RAD = 0.1
FOOTSTEP_TOLERANCE_M = 0.03  # a planned step lands this close to its target, or the plan is not performed
SETTLED_COM_SPEED_M_S = 0.05
FALL_PENALTY = 10.0
DIVERGED_PENALTY = 100.0
NOT_PERFORMED_PENALTY = 5.0
MISSED_GOAL_PENALTY = 30.0  # ABC 5: a missed catch is heavily penalised (also: slab not toppled, no hit)
NOT_SETTLED_PENALTY = 5.0
# joints whose reference moves more than this over [P, P + T] drive the motion (smaller excursions: a 0.01 rad
# tracking error moves a 0.17 rad neck's 90 % crossing by ~25 ms)
DRIVING_JOINT_RAD = 0.2
MAX_TIMING_LAG_S = 0.05  # s: no driving joint of a pose change should arrive later than this (or 0.1 T)
# Whether a motion must also be on time (``timing_lag_s`` <= ``timing_lag_bound_s``) to count as performed: every
# pose change and every interaction (a prop task's driving joints). A test switches it off to show what it adds.
ENFORCE_TIMING = True
# What a success must also look like (docs/physics.md, *Success*): a motion a researcher would accept, not only
# a score. Each is a figure of the Evaluation; a success never stands beside one that breaks its bound.
MAX_PLAN_COP_ERROR_M = 0.005  # planned vs executed CoP, outside impact windows: the plan is what happens
MAX_GROUND_FORCE_BW = 2.5  # peak vertical ground force, outside impact windows
MAX_AIRBORNE_S = 0.01  # both feet off the ground (feet planted: no flight)
MIN_COP_MARGIN_M = 0.001  # the measured CoP inside the feet: at an end, the other end carries nothing (a slack point,
# the foot about to roll)
NOT_PLAUSIBLE_PENALTY = 5.0  # x (1 + the worst excess over its bound, up to 1): CMA-ES keeps a slope


def verdict_bounds() -> dict[str, float]:
    """The fixed bounds of the verdict's rules, keyed by the figure each bounds (reports print them beside the
    figures; the tracking and timing bounds depend on the task and are figures of each evaluation)."""
    return {"max_plan_cop_error_m": MAX_PLAN_COP_ERROR_M, "peak_normal_force_bw": MAX_GROUND_FORCE_BW,
            "airborne_s": MAX_AIRBORNE_S, "min_cop_margin_m": MIN_COP_MARGIN_M,
            "final_pose_error_rad": FINAL_POSE_TOLERANCE_RAD, "final_com_speed_m_s": SETTLED_COM_SPEED_M_S}
TIMING_FRACTION = 0.9  # a driving joint has arrived when it covers this fraction of the reference's excursion
BODY_ON_FLOOR_Z_M = 0.0  # as the balance monitor's BODY_ON_FLOOR check: a non-foot body below the floor
# Figures only a recorded run (traces, ``cmrt simulate``) has, or has differently (a topple played out): a scoring
# run reports None (fall_direction from the capture point). Nothing the score depends on is among them.
TRACE_ONLY_FIELDS = ("max_foot_slip_m", "fall_direction", "fall_direction_source",
                     "after_fall_max_joint_speed_rad_s", "after_fall_peak_foot_force_bw", "after_fall_max_foot_lift_m",
                     "after_fall_floor_contact_s", "after_fall_airborne_s")


@dataclass(frozen=True)
class EvalRecord:
    """One candidate's score as the optimizer sees it (an ensemble's combined score for a robust run) and the
    simulation seconds it took."""

    objective: float
    fell: bool
    seconds: float
    success: bool = False


@dataclass(frozen=True)
class Evaluation:
    """What one clip scored; the fields of ``cmrt simulate --json``."""

    objective: float
    cop_error_norm: float
    penalty: float
    # the same samples against the controller's own reference CoP (the support centre in center mode, Winter's in
    # yu mode): how well each mode meets its own target, where the objective compares both on one scale
    cop_error_own_reference_norm: float
    success: bool
    performed: bool | None
    settled: bool
    fell: bool
    fall_time_s: float | None
    fall_reason: str | None
    diverged: bool
    max_cop_error_m: float
    min_cop_margin_m: float
    peak_normal_force_bw: float
    airborne_s: float
    max_joint_speed_rad_s: float
    tracking_error_rad: float | None
    tracking_bound_rad: float | None
    final_pose_error_rad: float
    final_com_speed_m_s: float
    n_samples: int
    task_success: bool | None = None
    # hand-prop interaction (None without a prop), before any fall: the first contact, the largest force
    # and the impulse over the clip; for a ball, how far the hands holding it are below the reference at the
    # end (signed), the largest |sag| since the grip, and how long they have been held within the bound
    first_contact_s: float | None = None
    peak_contact_force_n: float | None = None
    contact_impulse_n_s: float | None = None
    ball_sag_m: float | None = None
    ball_max_sag_m: float | None = None
    ball_held_s: float | None = None
    # stepping (task parameter ``stepping``): how many steps the supervisor took before any fall, and when
    # each lifted off
    steps: int = 0
    step_times_s: tuple[float, ...] = ()
    # ... the first lift-off after an unannounced push began (s after its start; None: no push, or no step after it:
    # people lift the foot 0.25-0.35 s after a push) and the hardest touchdown (peak vertical ground force within
    # IMPACT_WINDOW_S of each step's touchdown, in body weights; None: no touchdown)
    step_liftoff_after_push_s: float | None = None
    max_touchdown_force_bw: float | None = None
    # a footstep plan (Task.steps): how many of its steps landed before any fall, and the farthest one landed from
    # where it was asked to (m; None without a plan). All landed within FOOTSTEP_TOLERANCE_M: the plan performed
    footsteps_landed: int | None = None
    max_footstep_error_m: float | None = None
    # ... and how far each stance foot's own CoP rolled from heel toward toe between its touchdown and its next
    # lift-off, the least over the plan's stances (a fraction of heel to toe; None without such a stance). A
    # person's walk rolls from heel strike to toe-off, the whole foot
    min_stance_cop_roll: float | None = None
    # ... and a walk's pace (a plan of four steps or more): the CoM's mean forward speed from the second step's lift-off
    # to the last's - its steady steps, the start and the stop left out as a gait lab's walkway does (m/s; people walk
    # at 1.2-1.4, slowly at 0.6-0.8)
    walk_speed_m_s: float | None = None
    # the thorax's largest pitch from upright before any fall (deg, either way; the body stands at +3.7), for a clip
    # that steps: people walk with the trunk within a few degrees of upright
    max_thorax_pitch_deg: float | None = None
    # diagnostics (docs/controller.md, *Diagnostics*); the plan gap, timing lag and the figures above enter the verdict
    max_plan_cop_error_m: float | None = None  # planned vs executed CoP (recorded runs)
    max_foot_slip_m: float | None = None  # how far a heel/toe point slid along the support while planted on it
    timing_lag_s: float | None = None  # how late the motion was done (pose changes)
    timing_lag_bound_s: float | None = None  # ...and how late it may be to count as performed
    fall_direction: str | None = None  # "forward" / "backward" (None: no fall, or a blow-up)
    fall_direction_source: str | None = None  # "topple" (played out) or "capture_point" (a scoring run)
    after_fall_max_joint_speed_rad_s: float | None = None  # from the fall to the first non-foot floor contact
    after_fall_peak_foot_force_bw: float | None = None
    after_fall_max_foot_lift_m: float | None = None
    after_fall_floor_contact_s: float | None = None  # None: no body other than the feet reached the floor
    after_fall_airborne_s: float | None = None  # from the fall to the end of the record: nothing on the floor (a hop)
    # the one verdict rule (``success_rule`` names what "performed" means for this task): the rules this clip
    # broke, in order - "balance", "performed", "on_time", "settled", "plan", "ground_force", "airborne",
    # "cop_margin", "final_pose" - empty for a success
    failed_rules: tuple[str, ...] = ()
    success_rule: str = ""
    # a struck prop (the bag): the speed of the fist that first touched it, at the state that contact step
    # started from (m/s; None: no contact before any fall, or a prop that does not measure it)
    fist_speed_at_contact_m_s: float | None = None
    # ... and how extended that arm was then: the fist's distance from its shoulder over the arm's length (None: as
    # for the speed)
    fist_reach_at_contact: float | None = None

    def scored(self) -> Evaluation:
        """This evaluation without the trace-only figures: what a scoring run of the same clip gives."""
        return replace(self, **{name: None for name in TRACE_ONLY_FIELDS})


def _sample_index(task: Task, traj: Trajectory) -> np.ndarray:
    """Indices of the CoP samples: every ``cop_sample_step_s`` over [0, L), before any fall."""
    dt = float(traj.time_s[1] - traj.time_s[0]) if traj.time_s.size > 1 else 1.0
    every = max(1, int(round(task.cop_sample_step_s / dt)))
    idx = np.arange(0, traj.time_s.size, every)
    keep = traj.time_s[idx] < task.clip_s - 1e-9
    if traj.fall_time_s is not None:
        keep &= traj.time_s[idx] < traj.fall_time_s - 1e-9
    return idx[keep]


def _loaded(task: Task, traj: Trajectory, idx: np.ndarray) -> np.ndarray:
    weight = character().mass_kg * GRAVITY_M_S2
    return (traj.normal_force_n[idx] > MIN_FOOT_FORCE_FRACTION * weight) & np.isfinite(traj.cop_x_m[idx])


def cop_error_samples(task: Task, traj: Trajectory) -> np.ndarray:
    """e(t_k) at the task's sample step; NaN-free (dropped samples removed)."""
    idx = _sample_index(task, traj)
    idx = idx[_loaded(task, traj, idx)]
    return traj.cop_x_m[idx] - traj.support_center_x_m[idx]


def _window_index(task: Task, traj: Trajectory) -> np.ndarray:
    """CoP sample indices inside the task window [P, P + T] (before any fall)."""
    idx = _sample_index(task, traj)
    start, stop = task.task_window_s()
    t = traj.time_s[idx]
    return idx[(t >= start - 1e-9) & (t <= stop + 1e-9)]


def tracking_error_rad(task: Task, traj: Trajectory) -> float | None:
    """RMS error of the actuated joints against the reference over the task window [P, P + T]
    (the whole clip for a task without a pose change), at the CoP sample steps before any fall;
    None if balance was lost before the window."""
    idx = _window_index(task, traj)
    if idx.size == 0:
        return None
    dofs = list(character().actuated_dofs)
    q_ref = task.reference(traj.time_s[idx])[0]
    err = traj.qpos[idx][:, dofs] - q_ref[:, dofs]
    return float(np.sqrt(np.mean(err**2)))


def _before_fall(traj: Trajectory) -> np.ndarray:
    if traj.fall_time_s is None:
        return np.ones(traj.time_s.size, bool)
    return traj.time_s < traj.fall_time_s - 1e-9


def _performed(task: Task, traj: Trajectory, tracking: float | None, final_err: float,
               lag: float | None, lag_bound: float | None) -> tuple[bool | None, float | None, float | None]:
    """Whether the clip performed the motion (None: the task has nothing to perform), with the tracking bound
    and the timing-lag bound it was judged against (None when not used): a prop task met its goal, a pose change
    ended in its pose tracked within the RMS bound, a footstep plan landed every step; and with ``ENFORCE_TIMING``
    the driving joints of a pose change or an interaction arrived on time (``lag`` within ``lag_bound``)."""
    on_time = not ENFORCE_TIMING or lag is None or lag <= lag_bound + 1e-12
    if traj.task_success is not None:
        return traj.task_success and on_time, None, lag_bound
    steps_ok = None
    if task.footsteps_planned:  # a footstep plan or a gait: every step landed, each where it was asked to
        errors = np.abs(np.asarray(traj.footstep_errors_m, float))
        steps_ok = bool(len(errors) == task.footsteps_planned and np.all(errors <= FOOTSTEP_TOLERANCE_M))
    if task.end_pose_deg is None:
        return steps_ok, None, lag_bound
    start, stop = task.task_window_s()
    bound = task.tracking_bound_rad(np.arange(start, stop + 1e-9, task.cop_sample_step_s))
    performed = bool(final_err < FINAL_POSE_TOLERANCE_RAD and tracking is not None and tracking <= bound)
    performed = performed and on_time
    if steps_ok is not None:
        performed = performed and steps_ok
    return performed, bound, lag_bound


def success_rule(task: Task) -> str:
    """What "performed" means for this task, as the verdict names it (docs/physics.md, *Success*)."""
    if task.has_goal:
        return "interaction: goal met, on time"
    if task.footsteps_planned:
        return ("footsteps: every step within 3 cm, then " + ("the end pose" if task.end_pose_deg else "standing")
                + " in the stance over them")
    if task.end_pose_deg is not None:
        return "pose change: end pose, tracked, on time"
    return "standing in the stance over its feet" if task.feet_move else "standing"


def _excesses(ev: dict, fell: bool, pose_judged: bool) -> dict[str, float]:
    """Each plausibility rule's excess over its bound (> 0: broken), from the evaluation's figures. The final
    pose is a rule of its own where "performed" does not already judge it (standing, steps, props)."""
    out = {}
    if ev["max_plan_cop_error_m"] is not None:
        out["plan"] = ev["max_plan_cop_error_m"] / MAX_PLAN_COP_ERROR_M - 1.0
    out["ground_force"] = ev["peak_normal_force_bw"] / MAX_GROUND_FORCE_BW - 1.0
    out["airborne"] = ev["airborne_s"] / MAX_AIRBORNE_S - 1.0 if ev["airborne_s"] > MAX_AIRBORNE_S else -1.0
    out["cop_margin"] = (MIN_COP_MARGIN_M - ev["min_cop_margin_m"]) / 0.01
    if not fell and not pose_judged:
        out["final_pose"] = ev["final_pose_error_rad"] / FINAL_POSE_TOLERANCE_RAD - 1.0
    return out


def _verdict(task: Task, traj: Trajectory, settled: bool, performed: bool | None, lag: float | None,
             lag_bound: float | None, figures: dict) -> tuple[tuple[str, ...], float]:
    """The rules the clip broke, in order, and the worst plausibility excess (for the penalty)."""
    failed = []
    if traj.fell:
        failed.append("balance")
    late = ENFORCE_TIMING and lag is not None and lag_bound is not None and lag > lag_bound + 1e-12
    if performed is False and not (late and _only_late(task, traj, figures)):
        failed.append("performed")
    if late:
        failed.append("on_time")
    if not traj.fell and not settled:
        failed.append("settled")
    pose_change = task.end_pose_deg is not None and traj.task_success is None  # "performed" judged its end pose
    excess = _excesses(figures, traj.fell, pose_change)
    failed += [rule for rule, x in excess.items() if x > 0.0]
    worst = max((x for x in excess.values() if x > 0.0), default=0.0)
    return tuple(failed), worst


def _only_late(task: Task, traj: Trajectory, figures: dict) -> bool:
    """A motion not performed only because it was late (its pose, tracking and goal were met)."""
    if traj.task_success is not None:
        return bool(traj.task_success)
    bound = figures["tracking_bound_rad"]
    tracking = figures["tracking_error_rad"]
    return bool(figures["final_pose_error_rad"] < FINAL_POSE_TOLERANCE_RAD and tracking is not None
                and bound is not None and tracking <= bound)


def _penalty(task: Task, traj: Trajectory, failed: tuple[str, ...], tracking: float | None, bound: float | None,
             lag: float | None, lag_bound: float | None, worst_excess: float) -> float:
    """The penalties added to the CoP-error norm: a divergence, a fall (the earlier the more), not settling,
    a missed goal, a motion not performed or late (the further off the reference or the later, the more), a
    motion a person would not make (the further over its bound, the more)."""
    run_s = task.clip_s + task.tail_s
    if traj.diverged:
        return DIVERGED_PENALTY + (MISSED_GOAL_PENALTY if traj.task_success is False else 0.0)
    if traj.fell:
        penalty = FALL_PENALTY + 10.0 * max(run_s - (traj.fall_time_s or 0.0), 0.0) / run_s
    else:
        penalty = NOT_SETTLED_PENALTY if "settled" in failed else 0.0
    if traj.task_success is False:
        penalty += MISSED_GOAL_PENALTY
    elif ("performed" in failed or "on_time" in failed) and not traj.fell:
        excess = tracking / bound - 1.0 if tracking is not None and bound else 0.0
        if "performed" in failed and not (tracking is not None and bound):
            excess = 1.0
        if "on_time" in failed:  # late counts like off the reference: the worse of the two
            excess = max(excess, lag / lag_bound - 1.0)
        penalty += NOT_PERFORMED_PENALTY * (1.0 + float(np.clip(excess, 0.0, 1.0)))
    if worst_excess > 0.0 and not traj.fell:
        penalty += NOT_PLAUSIBLE_PENALTY * (1.0 + float(np.clip(worst_excess, 0.0, 1.0)))
    return penalty


def evaluate(task: Task, traj: Trajectory) -> Evaluation:
    """Score a simulated clip: the CoP-error 2-norm (the paper's objective) plus penalties for a fall, a
    missed goal, a motion not performed or late, not settling and a motion a person would not make; never
    raises on a failed clip. ``success`` is the one verdict rule: ``failed_rules`` empty."""
    weight = character().mass_kg * GRAVITY_M_S2
    idx = _sample_index(task, traj)
    idx = idx[_loaded(task, traj, idx)]
    e = traj.cop_x_m[idx] - traj.support_center_x_m[idx]
    norm = float(np.linalg.norm(e))
    own = traj.cop_x_m[idx] - traj.cop_ref_x_m[idx]
    margin = np.minimum(traj.cop_x_m[idx] - traj.support_lo_x_m[idx], traj.support_hi_x_m[idx] - traj.cop_x_m[idx])
    before = _before_fall(traj)
    contact = _contact_summary(traj, before)
    grf = before & ~_impact_windows(traj, contact["first_contact_s"], touchdowns=False)
    fz = traj.normal_force_n[grf]
    fz = fz[np.isfinite(fz)]
    dt = float(traj.time_s[1] - traj.time_s[0]) if traj.time_s.size > 1 else 0.0
    speeds = traj.max_joint_speed_rad_s[before]
    speeds = speeds[np.isfinite(speeds)]
    tracking = tracking_error_rad(task, traj)
    final_ok = bool(np.all(np.isfinite(traj.final_qpos)))
    final_err = task.final_pose_error_rad(traj.final_qpos) if final_ok else float("inf")

    lag, lag_bound = timing_s(task, traj)
    performed, bound, lag_bound = _performed(task, traj, tracking, final_err, lag, lag_bound)
    settled = not traj.fell and traj.final_com_speed_m_s < SETTLED_COM_SPEED_M_S
    figures = {
        "max_plan_cop_error_m": plan_cop_error_m(traj, contact["first_contact_s"]),
        "peak_normal_force_bw": float(fz.max() / weight) if fz.size else 0.0,
        "airborne_s": float(np.count_nonzero(fz < AIRBORNE_FORCE_FRACTION * weight) * dt),
        "min_cop_margin_m": float(margin.min()) if margin.size else 0.0,
        "final_pose_error_rad": final_err, "tracking_error_rad": tracking, "tracking_bound_rad": bound,
    }
    failed, worst = _verdict(task, traj, settled, performed, lag, lag_bound, figures)
    penalty = _penalty(task, traj, failed, tracking, bound, lag, lag_bound, worst)
    return Evaluation(
        objective=norm + penalty,
        cop_error_norm=norm,
        penalty=penalty,
        cop_error_own_reference_norm=float(np.linalg.norm(own[np.isfinite(own)])),
        success=not failed,
        performed=performed,
        settled=settled,
        fell=traj.fell,
        fall_time_s=traj.fall_time_s,
        fall_reason=None if traj.fall_reason is None else traj.fall_reason.value,
        diverged=traj.diverged,
        max_cop_error_m=float(np.max(np.abs(e))) if e.size else 0.0,
        min_cop_margin_m=figures["min_cop_margin_m"],
        peak_normal_force_bw=figures["peak_normal_force_bw"],
        airborne_s=figures["airborne_s"],
        max_joint_speed_rad_s=float(speeds.max()) if speeds.size else 0.0,
        tracking_error_rad=tracking,
        tracking_bound_rad=bound,
        final_pose_error_rad=final_err,
        final_com_speed_m_s=traj.final_com_speed_m_s,
        n_samples=int(e.size),
        task_success=traj.task_success,
        **contact,
        ball_sag_m=traj.prop_extras.get("ball_sag_m"),
        ball_max_sag_m=traj.prop_extras.get("ball_max_sag_m"),
        ball_held_s=traj.prop_extras.get("ball_held_s"),
        **_step_figures(task, traj, before, weight),
        max_plan_cop_error_m=figures["max_plan_cop_error_m"],
        max_foot_slip_m=foot_slip_m(traj),
        timing_lag_s=lag,
        timing_lag_bound_s=lag_bound,
        **fall_direction(traj),
        **after_fall(traj),
        failed_rules=failed,
        success_rule=success_rule(task),
        fist_speed_at_contact_m_s=_finite_or_none(traj.prop_extras.get("fist_speed_at_contact_m_s")),
        fist_reach_at_contact=_finite_or_none(traj.prop_extras.get("fist_reach_at_contact")),
    )


def _finite_or_none(x: float | None) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def _impact_windows(traj: Trajectory, first_contact_s: float | None, touchdowns: bool = True) -> np.ndarray:
    """Steps inside an impact (``IMPACT_WINDOW_S`` after the first hand-prop contact and, with ``touchdowns``,
    after each planned or reactive step's touchdown, and while an unannounced push acts): a contact's first
    instants are a collision, and a push is a force the controller does not know - neither is the plan at work.
    A touchdown's force is still judged (a step that slams down is not hidden); its plan gap is not."""
    t = traj.time_s
    inside = np.zeros(t.size, bool)
    if touchdowns and traj.push_n is not None:
        inside |= traj.push_n[: t.size] != 0.0
    starts = [] if first_contact_s is None else [first_contact_s]
    if touchdowns:
        starts += [float(f[1]) for f in traj.footprints]
        starts += list(traj.flat_times_s)  # a heel-first landing's toe: its own impact
    for start in starts:
        inside |= (t >= start - 1e-9) & (t < start + IMPACT_WINDOW_S)
    return inside


def step_liftoff_after_push_s(traj: Trajectory) -> float | None:
    """How long after an unannounced push began the first step lifted off (s; None: no push, or no step after it).
    The stepping supervisor decides from the balance feedback's delayed state, as a person reacts."""
    if traj.push_n is None or not traj.step_times_s:
        return None
    pushing = np.flatnonzero(traj.push_n[: traj.time_s.size] != 0.0)
    if pushing.size == 0:
        return None
    start = float(traj.time_s[pushing[0]])
    after = [float(t) - start for t in traj.step_times_s if t >= start - 1e-9]
    return round(min(after), 4) if after else None


def max_touchdown_force_bw(traj: Trajectory, before: np.ndarray, weight_n: float) -> float | None:
    """The hardest landing: peak vertical ground force within ``IMPACT_WINDOW_S`` of each step's touchdown, before
    any fall, in body weights (None: no touchdown). People land a step at ~1.1-1.5 BW walking."""
    t = traj.time_s
    peaks = []
    for footprint in traj.footprints:
        window = before & (t >= float(footprint[1]) - 1e-9) & (t < float(footprint[1]) + IMPACT_WINDOW_S)
        fz = traj.normal_force_n[window]
        fz = fz[np.isfinite(fz)]
        if fz.size:
            peaks.append(float(fz.max()) / weight_n)
    return max(peaks) if peaks else None


def _step_figures(task: Task, traj: Trajectory, before: np.ndarray, weight_n: float) -> dict:
    """The Evaluation's figures of the steps a clip took (none for planted feet) and of a plan's footsteps."""
    planned = bool(task.footsteps_planned)
    return {
        "steps": len(traj.step_times_s),
        "step_times_s": tuple(round(float(t), 4) for t in traj.step_times_s),
        "step_liftoff_after_push_s": step_liftoff_after_push_s(traj),
        "max_touchdown_force_bw": max_touchdown_force_bw(traj, before, weight_n),
        "footsteps_landed": len(traj.footstep_errors_m) if planned else None,
        "max_footstep_error_m": (float(np.max(np.abs(traj.footstep_errors_m)))
                                 if planned and traj.footstep_errors_m else None),
        "min_stance_cop_roll": stance_cop_roll(traj, weight_n) if planned else None,
        "walk_speed_m_s": walk_speed_m_s(traj, before) if planned else None,
        "max_thorax_pitch_deg": max_thorax_pitch_deg(traj, before) if traj.step_times_s else None,
    }


WALK_MIN_STEPS = 4  # a plan of this many steps or more walks: it has steady steps between its start and its stop


def walk_speed_m_s(traj: Trajectory, before: np.ndarray) -> float | None:
    """The CoM's mean forward speed between the second step's lift-off and the last step's, before any fall (None:
    fewer than ``WALK_MIN_STEPS`` steps, or no CoM sample there)."""
    lifts = traj.step_times_s
    if len(lifts) < WALK_MIN_STEPS:
        return None
    x, t = np.asarray(traj.com_m)[:, 0], np.asarray(traj.time_s)
    rows = np.flatnonzero(before & np.isfinite(x) & (t >= lifts[1] - 1e-9) & (t <= lifts[-1] + 1e-9))
    if rows.size < 2 or t[rows[-1]] <= t[rows[0]]:
        return None
    return float((x[rows[-1]] - x[rows[0]]) / (t[rows[-1]] - t[rows[0]]))


def max_thorax_pitch_deg(traj: Trajectory, before: np.ndarray) -> float | None:
    """The thorax's largest |pitch| in the world before any fall (the root's pitch and the lumbar joint's; deg)."""
    lumbar = character().dof("lumbar")
    qpos = np.asarray(traj.qpos)
    pitch = qpos[before, 2] + qpos[before, lumbar]
    pitch = pitch[np.isfinite(pitch)]
    return float(np.degrees(np.abs(pitch).max())) if pitch.size else None


def stance_cop_roll(traj: Trajectory, weight_n: float, edge_s: float = 0.02) -> float | None:
    """The least heel-to-toe roll of a stance foot's own CoP (its toe's share of its load: heel 0, toe 1) from its
    touchdown to its next lift-off: the mean over the first ``edge_s`` it carries more than 5 % of the body's weight
    against the mean over its last. A stance the body comes to rest on (no lift-off after it) is not counted."""
    force = np.asarray(traj.point_normal_force_n)
    if force.ndim != 2 or not traj.footprints:
        return None
    step_feet = [int(foot) for foot, _, _ in traj.footprints]  # step j's foot: its footprint's
    rolls = []
    for i, (foot, landed_s, _) in enumerate(traj.footprints):
        foot = int(foot)
        lifts = [traj.step_times_s[j] for j in range(i + 1, min(len(traj.step_times_s), len(step_feet)))
                 if step_feet[j] == foot]
        if not lifts:
            continue
        during = (traj.time_s >= landed_s) & (traj.time_s < lifts[0])
        heel, toe = force[during, 2 * foot], force[during, 2 * foot + 1]
        times = traj.time_s[during]
        loaded = np.isfinite(heel) & np.isfinite(toe) & (heel + toe > 0.05 * weight_n)
        if loaded.sum() < 2:
            continue
        share, times = toe[loaded] / (heel[loaded] + toe[loaded]), times[loaded]
        first, last = share[times <= times[0] + edge_s], share[times >= times[-1] - edge_s]
        rolls.append(float(last.mean() - first.mean()))
    return min(rolls) if rolls else None


def foot_slip_m(traj: Trajectory) -> float | None:
    """The farthest a heel/toe point slid along the support (m, in its frame) within one spell of being planted
    (touching it and carrying at least ``PLANTED_FORCE_N``), before any fall (recorded runs: the contacts of every
    control step; None for a scoring run). A planted foot on a floor of friction 1 slides well under a millimetre;
    Yu's slippery floor (0.08) lets it go."""
    contact, qpos = np.asarray(traj.point_contact), np.asarray(traj.qpos)
    force = np.asarray(traj.point_normal_force_n)
    if force.shape == contact.shape:  # a point whose load is not known (NaN) counts by its contact alone
        contact = np.where(np.isfinite(force) & (force < PLANTED_FORCE_N), 0.0, contact)
    if contact.ndim != 2 or qpos.ndim != 2 or contact.shape[0] != qpos.shape[0] or contact.size == 0:
        return None
    end = len(traj.time_s) if traj.fall_time_s is None else int(np.searchsorted(traj.time_s, traj.fall_time_s))
    rows = np.flatnonzero(np.isfinite(contact[:end]).all(axis=1) & np.isfinite(traj.qpos[:end]).all(axis=1))
    if rows.size == 0:
        return None
    ch = character()
    data = mujoco.MjData(ch.model)
    points = [g for pair in ch.foot_points for g in pair]
    anchor = np.full(len(points), np.nan)
    slip = 0.0
    for k in rows:
        data.qpos[:] = traj.qpos[k, : ch.model.nq]
        mujoco.mj_kinematics(ch.model, data)
        x = data.geom_xpos[points, 0]
        on = contact[k] > 0.5
        anchor = np.where(on, np.where(np.isnan(anchor), x, anchor), np.nan)
        if on.any():
            slip = max(slip, float(np.max(np.abs(x - anchor)[on])))
    return slip


def _contact_summary(traj: Trajectory, before: np.ndarray) -> dict:
    """First hand-prop contact, peak force and impulse before any fall (all None without a prop)."""
    return contact_summary(traj.prop_force_n, traj.time_s, before)


def contact_summary(force_n: np.ndarray, time_s: np.ndarray, before: np.ndarray) -> dict:
    """First hand-prop contact (s), peak force (N) and impulse (N s) over the steps ``before`` (a fall) of the
    hands' force on a prop at every physics step (``force_n``, at ``time_s``; all None without a prop): the planar
    and the 3D clips' figures."""
    if not np.isfinite(force_n).any() or not before.any():
        return {"first_contact_s": None, "peak_contact_force_n": None, "contact_impulse_n_s": None}
    f = np.nan_to_num(force_n[before])  # the same samples whether or not a topple was played out after
    dt = float(time_s[1] - time_s[0])
    touching = np.flatnonzero(f > CONTACT_FORCE_N)
    return {"first_contact_s": float(time_s[before][touching[0]]) if touching.size else None,
            "peak_contact_force_n": float(f.max()), "contact_impulse_n_s": float(f.sum() * dt)}


def plan_cop_error_m(traj: Trajectory, first_contact_s: float | None = None) -> float | None:
    """Largest |planned - executed CoP| over the control steps: the controller's ``ControlOutput.cop_x_m``
    against the CoP the touch sensors measured during the physics step its torques were first applied in. Only
    where the feet carry ``MIN_FOOT_FORCE_FRACTION`` of body weight, before any fall, outside the impact windows
    (the first hand-prop contact, each step's touchdown), no foot swinging (the record is NaN there). None when
    no control step qualifies."""
    weight = character().mass_kg * GRAVITY_M_S2
    keep = np.isfinite(traj.plan_cop_x_m) & np.isfinite(traj.cop_x_m) & _before_fall(traj)
    keep &= traj.normal_force_n >= MIN_FOOT_FORCE_FRACTION * weight
    keep &= ~_impact_windows(traj, first_contact_s)
    if not keep.any():
        return None
    return float(np.max(np.abs(traj.plan_cop_x_m[keep] - traj.cop_x_m[keep])))


def timing_lag_s(task: Task, traj: Trajectory) -> float | None:
    """How late the motion was done (s): ``timing_s``'s lag."""
    return timing_s(task, traj)[0]


def timing_s(task: Task, traj: Trajectory) -> tuple[float | None, float | None]:
    """How late the motion was done (s) and how late it may be (``timing_lag_bound_s``): the latest of the driving
    joints - of a sequence, its latest motion against that motion's own bound (``timed_motions``). For each
    actuated joint whose reference moves more than ``DRIVING_JOINT_RAD`` over [P, P + T] - the task's balance
    joint excepted, which
    the controller moves to keep its balance and a CMRT moves on purpose - the time it first covers
    ``TIMING_FRACTION`` of the reference's excursion (its largest departure from the pose at P inside the
    window: the end pose, or the via pose of an out-and-back motion) minus the time the reference does;
    a joint that never gets there before the clip ends (or the fall) counts as late as that end. The maximum
    over the joints, never below 0. One joint cannot hide behind another (a uniform-delay fit over all
    joints read 0.04 s for a bend whose trunk arrived 0.29 s late), a motion slowed down or done half way
    scores large, and tracking noise does not add lag. None for a task without a pose change, or when
    balance was lost before the window. (Sampled at the CoP sample steps.)

    A strike (a prop that is ``struck``: a bag, a pad) stops the limb that hits it: a joint that has not covered
    its 90 % when the hand first touches the prop inside [P, P + T] is judged at that contact - by how far it had
    got, against when the reference got that far. The rest of its excursion is the follow-through the target
    stops (a punch aimed through the bag), not the motion being late; the goal says the strike landed hard
    enough, fast enough and with the arm extended enough."""
    if task.end_pose_deg is None or task.duration_s <= 0 or traj.time_s.size < 2:
        return None, None
    idx = _sample_index(task, traj)
    t_all = traj.time_s[idx]
    ch = character()
    skip = set()
    if task.balance_joint:
        skip = {i for i, name in enumerate(ch.dof_names) if name.split("_")[0] == task.balance_joint}
    joints = [j for j in ch.actuated_dofs if j not in skip]
    return motion_lags(task, t_all, traj.qpos[idx], lambda keep: reachable(task.reference(t_all[keep])[0]),
                       joints, lambda start, stop: _strike_s(task, traj, start, stop))


def motion_lags(task: Task, t: np.ndarray, q: np.ndarray, reference_at: Callable[[np.ndarray], np.ndarray],
                joints: list[int], strike_at: Callable[[float, float], float | None]
                ) -> tuple[float | None, float | None]:
    """``timing_s``'s rule on any body: over the samples ``t`` (s; up to a fall) of the poses ``q``, each motion of
    ``timed_motions(task)`` over its own samples (a boolean mask ``keep``) against ``reference_at(keep)`` - the
    reachable reference there -, its ``joints`` (columns of ``q``) timed by ``joint_lags_s`` with a strike's first
    touch ``strike_at(start, stop)`` (None: no strike); (lag, bound) of the motion latest against its bound."""
    timed = []
    for start, stop, until, bound in timed_motions(task):
        keep = (t >= start - 1e-9) & (t < until - 1e-9)
        if not keep.any():
            continue
        lags = joint_lags_s(t[keep], q[keep], reference_at(keep), joints, t[keep] <= stop + 1e-9, start,
                            strike_at(start, stop))
        if lags:
            timed.append((max(0.0, float(max(lags))), bound))
    return latest_motion(timed)


def timed_motions(task: Task) -> list[tuple[float, float, float, float]]:
    """(start, end, judged until, lag bound) of each motion a clip is timed on: a task's one motion, [P, P + T],
    judged to the clip's end; a sequence's each (``cmrt.motion.sequence``), from its start until the next one's,
    against its own bound. Timed as one motion, a bend-rise-bend-rise was judged on its first bend alone (the
    excursion's peak): the 3D body's second bend, 52 ms late, went unseen."""
    motions = getattr(task, "motions", ())
    if not motions:
        start, stop = task.task_window_s()
        return [(start, stop, np.inf, timing_lag_bound_s(task))]
    untils = [m.start_s for m in motions[1:]] + [np.inf]
    return [(m.start_s, m.start_s + m.task.duration_s, until, timing_lag_bound_s(m.task))
            for m, until in zip(motions, untils, strict=True)]


def latest_motion(timed: list[tuple[float, float]]) -> tuple[float | None, float | None]:
    """Of (lag, bound) per motion, the motion latest against its own bound ((None, None): none timed)."""
    if not timed:
        return None, None
    return max(timed, key=lambda lag_bound: lag_bound[0] / lag_bound[1])


def joint_lags_s(t: np.ndarray, q: np.ndarray, q_ref: np.ndarray, joints: list[int], window: np.ndarray,
                 start_s: float, strike_s: float | None = None) -> list[float]:
    """How late each driving joint among ``joints`` (columns of ``q`` and ``q_ref``, sampled at ``t`` from the
    motion's start ``start_s``) arrived (s): ``timing_lag_s``'s rule on any body - a joint whose reference moves
    more than ``DRIVING_JOINT_RAD`` inside ``window`` is done when it first covers ``TIMING_FRACTION`` of that
    excursion (never: the last sample), less when its reference did; with ``strike_s``, a joint not done by the
    strike is judged by how far it had got then."""
    lags = []
    for j in joints:
        excursion = q_ref[window, j] - q_ref[0, j]
        peak = int(np.argmax(np.abs(excursion)))
        target = excursion[peak]
        if abs(target) <= DRIVING_JOINT_RAD:
            continue
        goal = TIMING_FRACTION * abs(target)
        done_at = _crossing_s(t, np.sign(target) * (q[:, j] - q_ref[0, j]), goal)
        if strike_s is not None and (done_at is None or done_at > strike_s + 1e-9):  # stopped by the target
            got = np.sign(target) * (np.interp(strike_s, t, q[:, j]) - q_ref[0, j])
            ref_at = _crossing_s(t, np.sign(target) * (q_ref[:, j] - q_ref[0, j]), min(got, goal))
            lags.append(strike_s - (start_s if ref_at is None else ref_at))
            continue
        ref_at = _crossing_s(t, np.sign(target) * (q_ref[:, j] - q_ref[0, j]), goal)
        lags.append((t[-1] if done_at is None else done_at) - ref_at)
    return lags


def _strike_s(task: Task, traj: Trajectory, start: float, stop: float) -> float | None:
    """The first hand contact with a struck prop inside the task window [P, P + T] (None: not a strike)."""
    if not prop_class(task.prop).struck:
        return None
    f = np.nan_to_num(traj.prop_force_n)
    hit = np.flatnonzero((f > CONTACT_FORCE_N) & (traj.time_s >= start - 1e-9) & (traj.time_s <= stop + 1e-9))
    return float(traj.time_s[hit[0]]) if hit.size else None


def reachable(q_ref: np.ndarray, body: str = "planar") -> np.ndarray:
    """The reference poses (n, nq) with each actuated joint kept ``stop_margin_rad`` inside its stops, as the
    controller keeps it - the planar one and the 3D one alike (a rise's straight knee ends 0.02 rad short of its
    0 rad stop: 90 % of a 15 deg excursion would otherwise leave it 0.35 deg to spare, and the stop's spring makes
    that last part slow; on the 3D body, without this, the knee was never done and a rise's lag read 0.76 s)."""
    ch = character(body)
    lo, hi = ch.joint_range_rad()  # per actuator
    margin = ControllerConfig.stop_margin_rad
    q = np.array(q_ref, dtype=float)
    columns = ch.model.jnt_qposadr[ch.model.actuator_trnid[:, 0]]  # the planar body's are its actuated dofs
    q[:, columns] = np.clip(q[:, columns], lo + margin, hi - margin)
    return q


def timing_lag_bound_s(task: Task) -> float:
    """How late a pose change may be and still count as performed: ``max_tracking_lag`` x T (0.1 T), and never
    more than ``MAX_TIMING_LAG_S`` - a slow motion is not allowed a long lag for being slow."""
    return min(task.max_tracking_lag * task.duration_s, MAX_TIMING_LAG_S)


def _crossing_s(t: np.ndarray, x: np.ndarray, goal: float) -> float | None:
    """When ``x`` first reaches ``goal``, linearly interpolated between the samples (None: never)."""
    above = np.flatnonzero(x >= goal - 1e-12)
    if above.size == 0:
        return None
    i = int(above[0])
    if i == 0 or x[i] == x[i - 1]:
        return float(t[i])
    return float(t[i - 1] + (goal - x[i - 1]) / (x[i] - x[i - 1]) * (t[i] - t[i - 1]))


def _fall_index(traj: Trajectory) -> int:
    return int(np.searchsorted(traj.time_s, traj.fall_time_s - 1e-9))


def _after_fall_span(traj: Trajectory) -> tuple[int, int, float | None] | None:
    """(fall step, last step, first non-foot floor contact s) of a topple played out after a fall (recorded
    runs); None if the record stops at the fall (scoring runs, blow-ups)."""
    if not traj.fell or traj.diverged or not traj.protective.any():
        return None
    k = _fall_index(traj)
    hit = np.flatnonzero(traj.lowest_body_z_m[k:] < BODY_ON_FLOOR_Z_M)
    if hit.size:
        return k, k + int(hit[0]), float(traj.time_s[k + hit[0]])
    return k, traj.time_s.size - 1, None


def fall_direction(traj: Trajectory) -> dict:
    """Which way the body went: ``forward`` / ``backward`` (None: no fall, or a blow-up). A topple played out
    (recorded runs): the side of the support centre at the fall the CoM is on when a body other than the feet
    first reaches the floor, or at the end of the record (``source`` "topple"). A scoring run stops at the fall:
    the edge of the feet the capture point has left at the fall, or, if it is still between them (a fall for
    another reason: a rolled foot, the CoM low), the sign of the CoM velocity (``source`` "capture_point")."""
    none = {"fall_direction": None, "fall_direction_source": None}
    if not traj.fell or traj.diverged:
        return none
    k = min(_fall_index(traj), traj.time_s.size - 1)
    center = traj.support_center_x_m[k]
    span = _after_fall_span(traj)
    if span is not None:
        d, source = traj.com_m[span[1], 0] - center, "topple"
    else:
        xi, vel = traj.fall_capture_point_x_m, traj.fall_com_vel_x_m_s
        if xi is None or vel is None:
            return none
        lo, hi = traj.support_lo_x_m[k], traj.support_hi_x_m[k]
        d = xi - hi if xi > hi else xi - lo if xi < lo else vel if vel != 0 else xi - center
        source = "capture_point"
    if not np.isfinite(d):
        return none
    return {"fall_direction": "forward" if d >= 0 else "backward", "fall_direction_source": source}


def after_fall(traj: Trajectory) -> dict:
    """How violent the topple after a fall is, from the fall to the first non-foot floor contact (or the end of
    the record): the largest actuated joint speed, the peak total foot force (body weights), the highest heel/toe
    lift above its settled height, and when that contact came. All None unless the topple was played out."""
    span = _after_fall_span(traj)
    if span is None:
        return {"after_fall_max_joint_speed_rad_s": None, "after_fall_peak_foot_force_bw": None,
                "after_fall_max_foot_lift_m": None, "after_fall_floor_contact_s": None, "after_fall_airborne_s": None}
    k, last, contact_s = span
    part = slice(k, last + 1)
    weight = character().mass_kg * GRAVITY_M_S2
    dofs = list(character().actuated_dofs)
    # a hop after the fall: neither the feet nor any other body on the floor, to the end of the record
    dt = float(traj.time_s[1] - traj.time_s[0])
    flying = (traj.normal_force_n[k:] < AIRBORNE_FORCE_FRACTION * weight) & (traj.lowest_body_z_m[k:] > 0.0)
    return {"after_fall_max_joint_speed_rad_s": float(np.nanmax(np.abs(traj.qvel[part][:, dofs]))),
            "after_fall_peak_foot_force_bw": float(np.nanmax(traj.normal_force_n[part]) / weight),
            "after_fall_max_foot_lift_m": float(np.nanmax(traj.point_lift_m[part])),
            "after_fall_floor_contact_s": contact_s, "after_fall_airborne_s": float(np.count_nonzero(flying) * dt)}
