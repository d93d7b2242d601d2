"""When and where to step, and the step itself (Wu and Zordan 2010, sections 4.1-4.2 and 5), for n
simulations at once.

The supervisor reads the character's momenta every control step. With L_x the horizontal linear
momentum, H_y the pitch angular momentum about the CoM and f_z = m g, damping both momenta at rates
d_l and d_h needs the centre of pressure

    p_des = c_x + (d_l L_x c_z + d_h H_y) / f_z                    (their eq. 5, sagittal plane)

When p_des (d_l = 4, d_h = 6) leaves the support, the feet cannot stop the body where it stands: it
steps. The foot lands centred on a more conservative p_des (d_l = 9, d_h = 18), the point from which
it can push the remaining momentum away. The capture-point variant is the same formula with d_h = 0
and d_l = sqrt(g / c_z): p_des is then the capture point c_x + v_x sqrt(c_z / g) (their eq. 7-8).

A step lasts ``step_time_s``. The swing foot's heel point travels a straight line from where it
lifted off to the target with a bell-shaped speed (the Gaussian exp(-(s - 1/2)^2 / 0.08) of the
step's phase s, scaled to cover the distance), rises and falls by a second such bell of height
``lift_m`` and stays flat; the controller tracks that path as a task-space objective and gives the swing foot no
support rows and no load. The CoM target follows a quadratic Bezier through the CoM at lift-off,
the stance foot's centre and the midpoint between the stance foot and the target. The swing foot
touching the floor after half the step ends it (double support again); the supervisor then keeps
watching, so several steps can follow.

Planar adaptation (documented in docs/stepping.md): in the sagittal plane both feet lie on the line
of the push, so the paper's "foot nearest to p_des" is ambiguous at the first step (the feet are
side by side: the right foot steps) and, after a step, would lift the foot the body is falling
onto. The foot that steps is the one farther from p_des: it swings past the other, which becomes
the pivot - a walking step, as people take it after a hard push.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.special import erf

from cmrt.body.character import GRAVITY_M_S2
from cmrt.control import kernel

MOMENTUM, CAPTURE_POINT = 1, 2  # the task parameter ``stepping``: 0 off, 1 momentum supervisor, 2 capture point
RULES = {MOMENTUM: "momentum", CAPTURE_POINT: "capture point"}
NO_SWING = -1
SETTLE_SPLIT_M = 0.41  # the split a step's full stance-knee bend is made for (a reactive step's longest, heel to heel)


@dataclass(frozen=True)
class GaitPattern:
    """How a footstep plan walks, beyond where the feet go: from its first touchdown on (the first step from standing
    is a start, not a gait cycle), while its steps are not steps back. Without it a 0.4 m / 0.5 s walk bounced:
    nothing held the CoM's height, the stance knee straightened as the other foot lifted, the CoM rose 4.7 cm, the
    ground force fell to 0.35 body weights and the CoP ran onto a toe; the trunk swung 20-25 deg forward each step.
    Measured, and what each part does: docs/stepping.md, *The walking pattern*."""

    momentum_gain: float = 10.0  # the plan's linear-momentum objective weighs this many times the standing one's
    # (the CoP the capture-point plan asks for, carried out; at 1 the executed CoP lagged it and broke ``plan``)
    height_drop_m: float = 0.047  # the CoM walks this far below its standing height in steps of height_drop_step_m
    # (in shorter ones by the square of their length: the hip's drop between two straight legs grows so), reached
    # over a step; a step bringing the feet together rises back to the standing height
    height_drop_step_m: float = 0.4
    vault_m: float = 0.01  # and rises this much over the stance leg at mid-swing (a bell; 0: cop_margin broken)
    height_weight: float = 0.3  # of the vertical linear-momentum objective (the horizontal's is 0.1 x momentum_gain)
    height_k: float = 50.0  # 1/s^2
    height_d: float = 14.0  # 1/s (about critical for height_k)
    roll_m: float = 0.05  # the capture-point plan's anchor travels from this far behind the stance foot's centre to
    # this far ahead over the stance (heel to toe: the stance foot's CoP rolls, as a person's does)


@dataclass(frozen=True)
class StepConfig:
    """The supervisor's gains and the step's shape. Values and why: docs/stepping.md."""

    rule: int = MOMENTUM  # MOMENTUM (eq. 5) or CAPTURE_POINT (d_h = 0, d_l = sqrt(g / c_z))
    trigger_d_l: float = 4.0  # 1/s, momentum damping of the "must I step?" test (paper: 4)
    trigger_d_h: float = 6.0  # 1/s, angular momentum damping of that test (paper: 6)
    place_d_l: float = 9.0  # 1/s, conservative damping for where the foot lands (paper: 9)
    place_d_h: float = 18.0  # 1/s (paper: 18)
    step_time_s: float = 0.4  # lift-off to touchdown
    lift_m: float = 0.05  # peak height of the heel point above the floor
    width: float = 0.08  # the speed and lift bells are exp(-(s - 1/2)^2 / width), s = t / step time (paper's
    # 0.08; read as sigma = 0.08 of the step time instead, the foot is asked for 5.6 m/s and 100 m/s^2 on a
    # 0.45 m step of 0.4 s and cannot follow: docs/stepping.md)
    # a step's foot objective (weight, stiffness 1/s^2, damping 1/s, critical): firm enough to win over the rest
    # of the plan, so the foot follows its path. With the controller's (10, 400) the walk's heel rose 2.6 of the
    # 5 cm asked, peaked late, came down at 0.19 m/s in the step's last quarter, scraped 1.3 cm at lift-off and
    # landed at 2.1 body weights; a reactive step's foot dragged 5.9-7.1 cm along the floor before it rose. With
    # these the foot follows the bell within 1-5 mm and lands at ~0.1 m/s. A tracked gait keeps the controller's
    # (docs/stepping.md, *Swing*)
    swing_weight: float = 100.0
    swing_k: float = 900.0
    swing_d: float = 60.0
    # a planned step forward lands heel first: its foot pitches toe-up over the second half of the swing to this at
    # touchdown (0: lands flat), then lowers its toe toward ``landing_pitch_rad`` past flat with the pitch objective
    # (weight, stiffness 1/s^2, damping 1/s). On the heel pad v0.6's 0.2 m walk landed at 1.39 body weights and its
    # stance feet's CoP rolled 0.75 of heel to toe; flat, 1.46 and -0.06 (docs/stepping.md, *Directed steps*)
    heel_strike_rad: float = 0.05
    landing_pitch_rad: float = 0.03
    landing_weight: float = 100.0
    landing_k: float = 9.0
    landing_d: float = 6.0
    min_step_m: float = 0.10  # the foot's centre lands at least this far from the pivot foot's centre
    max_step_m: float = 0.45  # and at most this far forward (0.86 m hip to ankle)
    max_back_step_m: float = 0.30  # and backward: the swing leg's reach behind a hip the push left over the
    # stance ankle (a 0.45 m backward step needed 0.88-0.90 m of leg: the foot hovered; docs/stepping.md)
    knee_bend_rad: float = 0.5  # added to the stance knee's reference during a forward step (hip and ankle
    # take -half each: the stance foot stays flat, the trunk upright): a straight stance leg cannot lower the hip
    back_knee_bend_rad: float = 0.8  # the same, stepping backward: the hip must come down 7 cm, not 3.5, for
    # the swing ankle to reach the floor behind it
    retarget_until: float = 0.3  # the target follows the momenta until this fraction of the step (the foot
    # has covered 0.6 % of its path): a push still going on at lift-off makes the step longer
    touchdown_after: float = 0.5  # contact of the swing foot counts as touchdown after this fraction
    min_double_support_s: float = 0.05  # after a touchdown, the next step waits at least this long
    gait: GaitPattern | None = GaitPattern()  # how a footstep plan's forward steps walk (None: the steps alone)

    @staticmethod
    def from_task(params: dict[str, float]) -> StepConfig | None:
        """The config a task's ``stepping``/``step_time_s``/``step_height_m`` parameters ask for (None: off)."""
        rule = int(round(params.get("stepping", 0.0)))
        if rule == 0:
            return None
        return StepConfig(rule=rule, step_time_s=params.get("step_time_s", StepConfig.step_time_s),
                          lift_m=params.get("step_height_m", StepConfig.lift_m))


def desired_cop_x(com_x, com_z, momentum_x, ang_momentum_y, mass_kg, d_l, d_h):
    """Eq. 5: the CoP that damps L_x at rate d_l and H_y at rate d_h (f_z = m g; heights above the floor)."""
    return com_x + (d_l * momentum_x * com_z + d_h * ang_momentum_y) / (mass_kg * GRAVITY_M_S2)


def swing_profile(s: np.ndarray, width: float) -> tuple[np.ndarray, ...]:
    """Progress along the path (0 -> 1) and lift shape (0 -> 1 -> 0) at phase ``s`` in [0, 1], with their
    first and second derivatives in s: (phi, phi', phi'', h, h', h'').

    Both are built on the bell exp(-(s - 1/2)^2 / width): the speed is that bell scaled so the path is
    covered exactly at s = 1; the lift is the bell shifted and scaled to be 0 at both ends and 1 mid-step."""
    sigma = math.sqrt(width / 2.0)
    u = (s - 0.5) / sigma
    edge = erf(0.5 / (sigma * math.sqrt(2.0)))  # Phi(0.5 / sigma) - Phi(-0.5 / sigma)
    phi = 0.5 * (erf(u / math.sqrt(2.0)) + edge) / edge
    bell = np.exp(-0.5 * u * u)
    dphi = bell / (sigma * math.sqrt(2.0 * math.pi) * edge)
    ddphi = -u / sigma * dphi
    floor = math.exp(-0.125 / sigma**2)  # the bell at s = 0 and 1
    scale = 1.0 / (1.0 - floor)
    return (phi, dphi, ddphi, (bell - floor) * scale, -u / sigma * bell * scale,
            (u * u - 1.0) / sigma**2 * bell * scale)


def _toe_up(s: np.ndarray, start: float = 0.5, end: float = 0.95) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A smoothstep from 0 at ``start`` to 1 at ``end`` of the step's phase ``s``, with its first and second
    derivatives in s: how far a planned foot has pitched toe-up toward its heel strike."""
    span = end - start
    u = np.clip((s - start) / span, 0.0, 1.0)
    inside = (s > start) & (s < end)
    return (u * u * (3.0 - 2.0 * u), np.where(inside, 6.0 * u * (1.0 - u) / span, 0.0),
            np.where(inside, (6.0 - 12.0 * u) / span**2, 0.0))


def bezier(s: np.ndarray, p0, p1, p2) -> tuple[np.ndarray, np.ndarray]:
    """Quadratic Bezier through control points p0, p1, p2 at s in [0, 1], and its derivative in s."""
    return (1 - s) ** 2 * p0 + 2 * s * (1 - s) * p1 + s**2 * p2, 2 * (1 - s) * (p1 - p0) + 2 * s * (p2 - p1)


def _dcm_start(xi_end: float, anchor_start: float, anchor_end: float, length_s: float, omega: float) -> float:
    """Where the capture point must be for it to reach ``xi_end`` after ``length_s`` over a CoP moving linearly from
    ``anchor_start`` to ``anchor_end``: xi' = omega (xi - p) solved backward (p' / omega ahead of a moving CoP)."""
    lead = (anchor_end - anchor_start) / max(length_s, 1e-3) / omega
    return anchor_start + lead + (xi_end - anchor_end - lead) * math.exp(-omega * length_s)


@dataclass(frozen=True)
class StepCommand:
    """What the supervisor asks of the controller this control step, for the rows it was given."""

    swing_foot: np.ndarray  # (k,) float: -1, 0 (right) or 1 (left)
    swing_target: np.ndarray  # (k, kernel.N_SWING): heel point x, z, foot pitch; rates; accelerations; stance knee
    # bend; swing knee bend; whether the swing leg tracks the reference motion
    com_ref_x_m: np.ndarray  # (k,) CoM target on the Bezier (NaN: not stepping, the task's own target)
    com_ref_vel_x_m_s: np.ndarray  # (k,)
    cop_x_m: np.ndarray | None = None  # (k,) the CoP a footstep plan asks for (NaN: the task's own)
    arms_rad: np.ndarray | None = None  # (k, 3, 2): the shoulders' (right, left) angle, rate and acceleration added
    # to the reference (a plan's arm swing; None: none)

    def com_targets(self, com_ref: np.ndarray, com_ref_vel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The task's CoM target where no foot swings, the step's Bezier where one does (a footstep plan's
        target wherever it gives one)."""
        stepping = np.isfinite(self.com_ref_x_m)  # (a tracked gait's swing gives none: the task's own target)
        return np.where(stepping, self.com_ref_x_m, com_ref), np.where(stepping, self.com_ref_vel_x_m_s, com_ref_vel)

    def cop_target(self, cop_ref: np.ndarray) -> np.ndarray:
        """The task's CoP target, or a footstep plan's where it gives one."""
        return cop_ref if self.cop_x_m is None else np.where(np.isfinite(self.cop_x_m), self.cop_x_m, cop_ref)

    def rows(self, idx: np.ndarray) -> StepCommand:
        """The command of a subset of its rows."""
        return StepCommand(self.swing_foot[idx], self.swing_target[idx], self.com_ref_x_m[idx],
                           self.com_ref_vel_x_m_s[idx], None if self.cop_x_m is None else self.cop_x_m[idx],
                           None if self.arms_rad is None else self.arms_rad[idx])

    def with_arms(self, refs: tuple[np.ndarray, ...], shoulder_dofs: tuple[int, int]) -> tuple[np.ndarray, ...]:
        """The reference (q, qd, qdd; shared (nv,) or per row (k, nv)) with the arm swing added at the shoulders."""
        if self.arms_rad is None or not np.any(self.arms_rad):
            return refs
        k = self.arms_rad.shape[0]
        out = []
        for order, r in enumerate(refs):
            rows = np.array(np.broadcast_to(r, (k, r.shape[-1])))
            rows[:, list(shoulder_dofs)] += self.arms_rad[:, order]
            out.append(rows)
        return tuple(out)


@dataclass(frozen=True)
class StepPlan:
    """Footsteps asked for (``cmrt.motion.footsteps``), as the supervisor takes them: per step the foot (0 right,
    1 left), where its centre lands (m from the start stance's centre), its duration and its lift-off time (NaN:
    ``double_support_s`` after the step before landed; the first at ``first_step_s``)."""

    foot: np.ndarray
    x_m: np.ndarray
    duration_s: np.ndarray
    start_s: np.ndarray
    first_step_s: float
    double_support_s: float
    com_stiffness: float = 10.0  # 1/s^2: the controller's k_l (the CoM target carries the acceleration / k_l)


STEP_ADJUST_GAIN = 0.5  # a planned step in the first half of its swing lands this fraction of the capture
# point's error (as it will be at touchdown, less STEP_ADJUST_DEAD_M) beyond its target. Measured on pushes during
# the walk: without it +150 N at 2.0 s and +200 N at 1.5 s fell; with 0.5 both were survived; 1.0 fell at +200 N
STEP_ADJUST_DEAD_M = 0.05  # errors smaller than this move no step: without the dead zone the unpushed two-step
# plans of 0.3 m / 0.6 s and 0.4 m / 0.6 s fell (every small error moved a landing)


def step_adjustment_m(error_td_m: float, dead_m: float = STEP_ADJUST_DEAD_M) -> float:
    """How far a push moves a step's landing: ``STEP_ADJUST_GAIN`` of the capture point's error at touchdown beyond
    a dead zone of ``dead_m`` (a footstep plan's and a tracked gait's steps alike)."""
    return STEP_ADJUST_GAIN * math.copysign(max(abs(error_td_m) - dead_m, 0.0), error_td_m)


DCM_GAIN = 2.0  # the CoP moves (1 + DCM_GAIN) times the capture point's error beyond the plan's anchor (1, 4
# and 6 measured: no better)
SWING_KNEE_BEND_RAD = 1.0  # added to the swing knee of a plan's step at mid-swing (a bell, with the lift): a
# person's swing knee flexes ~1 rad. Measured in the walk: without it the knee stayed straight (0.03 rad) at
# mid-swing and the heel scuffed 12 cm along the floor; 0.4 and 0.7 rad left 5.4 and 3.2 cm, 1.0 only the 2.3 cm
# the first step's heel slides before it lifts
SWING_KNEE_UNTIL = 0.8  # that bend comes and goes within this fraction of the step: the foot is down to the floor
# before touchdown, not pulled down at it (over the whole step, two 0.3 m steps touched down at 0.33 m/s; 0.8: 0.28;
# 0.7: 0.24, but the closing step of three 0.3 m steps then landed at 2.64 body weights, 2.35 at 0.8)
TAKEOVER_ERROR_M = 0.06  # in double support, the momentum rule's call for a step (p_test beyond the feet) hands
# a plan to the reactive rule when the capture point is also this far off the plan's: a push. Measured without a
# push, while p_test was beyond the feet: at most 0.035 m in the walk, 0.053 m in two 0.4 m steps of 0.6 s; with
# +200 N at 2.0 s in the walk it passed 0.06 m 0.04 s before the capture point left the feet
ARM_SWING_RAD_PER_M = 0.6  # a planned step swings the arms opposite the legs, each shoulder this many rad per m of
# the step (foot to stance foot at landing): 0.24 rad (14 deg) each way in the walk's 0.4 m steps, 0.12 at 0.2 m
# (people: about 10-20 deg each way at 1-1.3 m/s). The arm on the swinging leg's side goes back as the leg goes forward
PLANNED_TOUCHDOWN_AFTER = 0.85  # a planned swing foot touching the floor counts as landed after this fraction of
# its step (a reactive one after ``touchdown_after``): at 0.5 the second step of a 0.3 m plan grazed the floor at
# mid-swing and "landed" 35 cm short


FLAT_WATCH_S = 0.3  # a landed foot standing on all its points this soon after its touchdown landed in two contacts


class LandingWatch:
    """When each landed foot first stands on both its points: a foot that lands heel first meets the floor twice,
    and its toe's contact is an impact of its own (``cmrt.sim.objective``: its plan gap is not judged). Watched by
    the steppers from the contacts they are given, so a recorded clip and an unrecorded one are judged alike."""

    def __init__(self, n: int):
        self.foot = np.full(n, NO_SWING)  # the foot watched since its touchdown, per simulation
        self.since_s = np.zeros(n)
        self.times: list[list[float]] = [[] for _ in range(n)]  # when a landed foot first stood on both points

    def landed(self, sim: int, foot: int, time_s: float) -> None:
        self.foot[sim], self.since_s[sim] = foot, time_s

    def update(self, ids: np.ndarray, time_s: float, contact: np.ndarray) -> None:
        """Look at rows ``ids``' contacts (k, 4) now, before this control step's touchdowns."""
        rows = np.flatnonzero(self.foot[ids] >= 0)
        if rows.size == 0:
            return
        foot, since = self.foot[ids[rows]], self.since_s[ids[rows]]
        flat = contact[rows, 2 * foot].astype(bool) & contact[rows, 2 * foot + 1].astype(bool)
        flat &= time_s > since + 1e-9
        expired = time_s >= since + FLAT_WATCH_S
        for r in rows[flat & ~expired]:
            self.times[ids[r]].append(time_s)
        self.foot[ids[rows[flat | expired]]] = NO_SWING


class StepSupervisor:
    """Per-simulation stepping state of a batch of n clips, advanced every control step by ``update``. With a
    ``plan`` it takes those steps, each when it is due, moving a pushed step's landing; a push the plan cannot
    absorb hands the body to reactive steps until it is at rest, and the plan goes on after them
    (``_take_over``)."""

    def __init__(self, n: int, config: StepConfig, heel_to_center_m: float, foot_length_m: float,
                 plan: StepPlan | None = None, stance: Callable[[float, float], np.ndarray] | None = None):
        self.config = config
        self.stance = stance  # the legs' offsets from the reference (right, left x hip, knee, ankle; rad) to stand
        # over feet with heel points at (right x, left x) m (``cmrt.body.stance``); None: the reference's legs
        self.stance_offsets = np.zeros((n, 6))  # those of the feet where the last step landed
        self.heel_first = np.zeros(n, bool)  # the step under way, or the last one, lands heel first
        self.arm_from_rad = np.zeros((n, 2))  # a planned step's shoulders (right, left) at its lift-off ...
        self.arm_to_rad = np.zeros((n, 2))  # ... and at its touchdown (ARM_SWING_RAD_PER_M)
        self.plan = plan
        self.next_planned = np.zeros(n, int)  # the plan's next step
        self.planned = np.zeros(n, bool)  # the step under way is the plan's
        self.origin_x = np.full(n, np.nan)  # the start stance's centre (the plan's x = 0)
        self.duration_s = np.full(n, config.step_time_s)  # of the step under way
        self.plan_offset_m = np.zeros(n)  # added to the plan's later steps: the supervisor moved one of them
        self.dcm_error_m = np.zeros(n)  # the capture point's lead on the plan's (xi - xi_ref) at the last control step
        self.mirrored = np.zeros(n, int)  # 1: the plan's later steps are taken by the other foot (after reactive
        # steps, the plan goes on with the trailing foot)
        self.recovering = np.zeros(n, bool)  # since then: reactive steps until at rest again, then the plan goes on
        self.placement_error_m: list[list[tuple[float, float]]] = [[] for _ in range(n)]  # (touchdown s, landed
        # - planned centre m) of every planned step
        self.heel_to_center_m = heel_to_center_m  # heel point to the middle of heel and toe points
        self.foot_length_m = foot_length_m  # heel point to toe point
        self.swing = np.full(n, NO_SWING)
        self.t0 = np.zeros(n)
        self.start_heel_x = np.zeros(n)
        self.target_heel_x = np.zeros(n)
        self.com0_x = np.zeros(n)
        self.com0_z = np.zeros(n)  # the CoM's height at a planned step's lift-off ...
        self.touchdown_z = np.zeros(n)  # ... at the last touchdown ...
        self.standing_z = np.full(n, np.nan)  # ... and where the plan started
        self.pivot_x = np.zeros(n)
        self.direction = np.zeros(n)
        self.last_touchdown_s = np.full(n, -np.inf)
        self.step_times: list[list[float]] = [[] for _ in range(n)]  # lift-off times
        self.footprints: list[list[tuple[int, float, float]]] = [[] for _ in range(n)]  # (foot, time, heel x)
        self.flat = LandingWatch(n)

    def _gains(self, com_z: np.ndarray, place: bool) -> tuple[np.ndarray, np.ndarray]:
        c = self.config
        if c.rule == CAPTURE_POINT:
            return np.sqrt(GRAVITY_M_S2 / np.maximum(com_z, 1e-3)), np.zeros_like(com_z)
        return (np.full_like(com_z, c.place_d_l if place else c.trigger_d_l),
                np.full_like(com_z, c.place_d_h if place else c.trigger_d_h))

    def _target_heel(self, rows, pivot_center, p_place, direction):
        c = self.config
        longest = np.where(direction > 0, c.max_step_m, c.max_back_step_m)
        reach = np.clip((p_place - pivot_center) * direction, c.min_step_m, longest)
        return pivot_center + direction * reach - self.heel_to_center_m

    def update(self, ids: np.ndarray, time_s: float, com_x: np.ndarray, com_z: np.ndarray, momentum_x: np.ndarray,
               ang_momentum_y: np.ndarray, mass_kg: np.ndarray, contact: np.ndarray, point_x: np.ndarray,
               cmrt: tuple[np.ndarray, np.ndarray] | None = None,
               felt: tuple[np.ndarray, ...] | None = None) -> StepCommand:
        """Advance simulations ``ids`` to ``time_s`` (a control step) and return what the controller should do.

        ``contact`` (k, 4) and ``point_x`` (k, 4): heel_r, toe_r, heel_l, toe_l on the floor / their x.
        ``cmrt``: the CMRT's displacement and rate of each row (a footstep plan's capture point moves with them).
        ``felt``: (com_x, com_z, momentum_x, ang_momentum_y) as the balance feedback feels them, its delay ago: the
        reactive decisions - whether to step, where, how far to stretch a step under way - are a person's reaction
        and are made from them (None: from the state of now); the feet are felt as they touch now."""
        c = self.config
        new = np.isnan(self.origin_x[ids])
        if new.any():  # the plan's x = 0: where the feet start, and the CoM's standing height
            self.origin_x[ids[new]] = 0.5 * (point_x[new].min(axis=1) + point_x[new].max(axis=1))
            self.standing_z[ids[new]] = com_z[new]
        self._touchdowns(ids, time_s, contact, point_x, com_z)
        swing = self.swing[ids]

        f_x, f_z, f_lx, f_hy = (com_x, com_z, momentum_x, ang_momentum_y) if felt is None else felt
        d_l, d_h = self._gains(f_z, place=False)
        p_test = desired_cop_x(f_x, f_z, f_lx, f_hy, mass_kg, d_l, d_h)
        d_l, d_h = self._gains(f_z, place=True)
        p_place = desired_cop_x(f_x, f_z, f_lx, f_hy, mass_kg, d_l, d_h)
        foot_down = contact[:, 0::2] | contact[:, 1::2]  # (k, 2)
        on = np.repeat(foot_down, 2, axis=1)
        with np.errstate(invalid="ignore"):
            lo = np.where(on, point_x, np.inf).min(axis=1)
            hi = np.where(on, point_x, -np.inf).max(axis=1)
            outside = foot_down.all(axis=1) & ((p_test < lo) | (p_test > hi))
        if self.plan is not None:  # a plan under way leaves the momenta to its capture-point plan (the trigger
            # fires at brisk touchdowns, and reactive steps then replaced the plan's for good: measured; also when
            # let in only with the plan's CoP 5 or 10 cm beyond the feet) unless a push overwhelmed it; after the
            # plan it watches again
            outside = self._take_over(ids, time_s, outside, foot_down, point_x)
        ready = (swing < 0) & (time_s - self.last_touchdown_s[ids] >= c.min_double_support_s)
        start = np.flatnonzero(outside & ready)
        if start.size:
            self._start_reactive(ids, start, time_s, com_x, point_x, (p_test, p_place))
            swing = self.swing[ids]
        if self.plan is not None:
            self._start_planned(ids, time_s, (com_x, com_z), point_x, swing < 0)
            swing = self.swing[ids]
        phase = (time_s - self.t0[ids]) / self.duration_s[ids]

        # retarget while the foot has hardly moved: momentum a push is still adding lengthens the step
        early = (swing >= 0) & (phase <= c.retarget_until)
        reactive = np.flatnonzero(early & ~self.planned[ids])
        if reactive.size:
            sims = ids[reactive]
            pivot = self.pivot_x[sims]
            self.target_heel_x[sims] = self._target_heel(reactive, pivot, p_place[reactive], self.direction[sims])

        command = self._command(ids, np.clip(phase, 0.0, 1.0), phase)
        if self.plan is not None:  # a footstep plan's targets: its CoM height (a walking pattern's), CoM and CoP
            self._gait_height(command, ids, np.clip(phase, 0.0, 1.0), phase)
            self._walk_targets(command, ids, time_s, com_x, com_z, momentum_x / mass_kg, point_x, contact, cmrt)
        return command

    def _start_reactive(self, ids: np.ndarray, start: np.ndarray, time_s: float, com_x: np.ndarray,
                        point_x: np.ndarray, p: tuple[np.ndarray, np.ndarray]) -> None:
        """Lift off a reactive step in rows ``start`` of ``ids``: the trailing foot toward ``p`` (p_test: the
        direction; p_place: where it lands)."""
        c = self.config
        p_test, p_place = p
        heel_x, toe_x = point_x[start][:, 0::2], point_x[start][:, 1::2]  # (k, 2) per foot
        centers = 0.5 * (heel_x + toe_x)
        # the trailing foot steps (ties: the right foot); the other is the pivot
        dist = np.abs(centers - p_test[start, None])
        foot = np.where(dist[:, 1] > dist[:, 0] + 1e-3, 1, 0)
        pivot = centers[np.arange(start.size), 1 - foot]
        direction = np.sign(p_test[start] - pivot)
        direction[direction == 0] = 1.0
        sims = ids[start]
        self.swing[sims] = foot
        self.t0[sims] = time_s
        self.start_heel_x[sims] = heel_x[np.arange(start.size), foot]
        self.com0_x[sims] = com_x[start]
        self.pivot_x[sims] = pivot
        self.direction[sims] = direction
        self.target_heel_x[sims] = self._target_heel(start, pivot, p_place[start], direction)
        self.duration_s[sims] = c.step_time_s
        if self.plan is not None:  # taking over from a plan: as long as its next step (0.4 s reactive steps
            # from a walk's split stance had 0.65 m to swing: the foot dragged on the floor)
            nxt = self.plan.duration_s[np.minimum(self.next_planned[sims], self.plan.foot.size - 1)]
            self.duration_s[sims] = np.where(self.recovering[sims], nxt, c.step_time_s)
        self.planned[sims] = self.heel_first[sims] = False  # a reactive step lands flat
        for s in sims:
            self.step_times[s].append(time_s)

    def _touchdowns(self, ids: np.ndarray, time_s: float, contact: np.ndarray, point_x: np.ndarray,
                    com_z: np.ndarray) -> None:
        """End the steps of rows ``ids`` whose swing foot is on the floor late enough in its step, recording the
        footprint (and, for a planned step, where it landed against its target)."""
        self.flat.update(ids, time_s, contact)
        swing = self.swing[ids]
        rows = np.flatnonzero(swing >= 0)
        if rows.size == 0:
            return
        phase = (time_s - self.t0[ids[rows]]) / self.duration_s[ids[rows]]
        foot = swing[rows]
        after = np.where(self._plan_shaped(ids[rows]), PLANNED_TOUCHDOWN_AFTER, self.config.touchdown_after)
        down = (contact[rows, 2 * foot] | contact[rows, 2 * foot + 1]) & (phase >= after)
        for r in rows[down]:
            sim = ids[r]
            self.footprints[sim].append((int(swing[r]), time_s, float(point_x[r, 2 * swing[r]])))
            self.flat.landed(sim, int(swing[r]), time_s)
            if self.planned[sim]:  # where its centre landed against where it was asked to
                landed = 0.5 * (point_x[r, 2 * swing[r]] + point_x[r, 2 * swing[r] + 1])
                self.placement_error_m[sim].append(
                    (time_s, float(landed - (self.target_heel_x[sim] + self.heel_to_center_m))))
            if self.stance is not None:
                self.stance_offsets[sim] = self.stance(float(point_x[r, 0]), float(point_x[r, 2]))
        self.swing[ids[rows[down]]] = NO_SWING
        self.last_touchdown_s[ids[rows[down]]] = time_s
        self.touchdown_z[ids[rows[down]]] = com_z[rows[down]]

    def _start_planned(self, ids: np.ndarray, time_s: float, com: tuple[np.ndarray, np.ndarray], point_x: np.ndarray,
                       idle: np.ndarray) -> None:
        """Lift off the plan's next step in rows ``ids`` where it is due and no foot swings (``com``: x, z)."""
        plan, c = self.plan, self.config
        com_x, com_z = com
        nxt = self.next_planned[ids]
        left = nxt < plan.foot.size
        when = np.where(left, self._due_s(ids), np.inf)
        ready = (idle & left & ~self.recovering[ids] & (time_s >= when - 1e-9)
                 & (time_s - self.last_touchdown_s[ids] >= c.min_double_support_s))
        rows = np.flatnonzero(ready)
        if rows.size == 0:
            return
        sims, j = ids[rows], nxt[rows]
        foot = plan.foot[j] ^ self.mirrored[sims]
        centers = 0.5 * (point_x[rows][:, 0::2] + point_x[rows][:, 1::2])  # (k, 2) per foot
        pivot = centers[np.arange(rows.size), 1 - foot]
        target_center = self.origin_x[sims] + plan.x_m[j] + self.plan_offset_m[sims]
        direction = np.sign(target_center - pivot)
        direction[direction == 0] = 1.0
        self.swing[sims] = foot
        self.t0[sims] = time_s
        self.start_heel_x[sims] = point_x[rows, 2 * foot]
        self.com0_x[sims] = com_x[rows]
        self.com0_z[sims] = com_z[rows]
        self.pivot_x[sims] = pivot
        self.direction[sims] = direction
        self.target_heel_x[sims] = target_center - self.heel_to_center_m
        self.duration_s[sims] = plan.duration_s[j]
        self.planned[sims] = True
        self.heel_first[sims] = (direction > 0) & (c.heel_strike_rad > 0.0)
        if c.gait is not None:  # a step closing the feet lands flat beside the stance foot, under the body
            self.heel_first[sims] &= target_center - pivot > c.min_step_m
        self.next_planned[sims] = j + 1
        # the arms swing opposite the legs: at touchdown the swinging leg's arm is back (+), the other forward;
        # the plan's last step brings them back to hang
        self.arm_from_rad[sims] = self.arm_to_rad[sims]
        amplitude = ARM_SWING_RAD_PER_M * np.abs(target_center - pivot) * (j + 1 < plan.foot.size)
        side = np.where(foot[:, None] == np.arange(2)[None, :], 1.0, -1.0)  # +1 on the swinging leg's side
        self.arm_to_rad[sims] = side * amplitude[:, None]
        for sim in sims:
            self.step_times[sim].append(time_s)

    def _due_s(self, ids: np.ndarray) -> np.ndarray:
        """When the plan's next step of rows ``ids`` lifts off: its own start time, else ``double_support_s``
        after the last touchdown, else (no step yet) ``first_step_s``."""
        plan = self.plan
        after = np.where(np.isfinite(self.last_touchdown_s[ids]), self.last_touchdown_s[ids] + plan.double_support_s,
                         plan.first_step_s)
        start = plan.start_s[np.minimum(self.next_planned[ids], plan.foot.size - 1)]
        return np.where(np.isnan(start), after, start)

    def _plan_shaped(self, sims: np.ndarray) -> np.ndarray:
        """Which simulations' step is shaped as a plan's (its crouch, knee bend and touchdown rule): a planned
        step, or a reactive one taking over a pushed plan."""
        return self.planned[sims] | self.recovering[sims]

    def _crouch_scale(self, sims: np.ndarray) -> np.ndarray:
        """How much of a step's knee bend a planned step of simulations ``sims`` needs: (reach / 0.41 m)^2, at
        most 1 (the hip's drop between two straight legs grows with their split squared)."""
        reach = np.abs(self.target_heel_x[sims] + self.heel_to_center_m - self.pivot_x[sims])
        return np.minimum(1.0, (reach / SETTLE_SPLIT_M) ** 2)

    def _take_over(self, ids: np.ndarray, time_s: float, outside: np.ndarray, foot_down: np.ndarray,
                   point_x: np.ndarray) -> np.ndarray:
        """The reactive trigger of rows ``ids`` following a plan: ``outside`` (the momentum rule's call for a step)
        where the plan is done, or where a push overwhelmed it. A push overwhelms a plan in double support when the
        rule calls for a step and the capture point is more than ``TAKEOVER_ERROR_M`` off the plan's: reactive
        steps (each as long as the plan's next) follow while the momenta ask for them. Back at rest, the plan goes
        on from the feet where they are, with the trailing foot, its next step as long as planned."""
        plan = self.plan
        pushed = outside & (np.abs(self.dcm_error_m[ids]) > TAKEOVER_ERROR_M) & ~self.recovering[ids]
        self.recovering[ids[pushed]] = True
        rested = np.flatnonzero(self.recovering[ids] & (self.swing[ids] < 0) & foot_down.all(axis=1) & ~outside
                                & (time_s - self.last_touchdown_s[ids] >= plan.double_support_s))
        for r in rested:
            sim = ids[r]
            self.recovering[sim] = False
            j = self.next_planned[sim]
            if j >= plan.foot.size:
                continue
            self.mirrored[sim] = plan.foot[j] ^ (1 - self.footprints[sim][-1][0])  # the trailing foot steps next
            stance = 1 - (plan.foot[j] ^ self.mirrored[sim])
            center = 0.5 * (point_x[r, 2 * stance] + point_x[r, 2 * stance + 1])
            self.plan_offset_m[sim] = center - self.origin_x[sim] - (plan.x_m[j - 1] if j else 0.0)
        return outside & ((self.next_planned[ids] >= plan.foot.size) | self.recovering[ids])

    def _walk_targets(self, command: StepCommand, ids: np.ndarray, time_s: float, com_x: np.ndarray,
                      com_z: np.ndarray, vel_x: np.ndarray, point_x: np.ndarray, contact: np.ndarray,
                      cmrt: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """The CoM and CoP targets of rows that follow a footstep plan, in place, from its capture point (DCM)
        plan: each remaining step's stance foot is the anchor of a segment (the double support before its lift-off
        and its swing); the capture point must come to rest over the feet after the last. Backward from there,
        xi_start = a + (xi_end - a) exp(-omega L) per segment gives where the capture point should be now; the
        CoP is the anchor plus (1 + DCM_GAIN) times the error, within the support; the CoM target asks for the
        pendulum's acceleration omega^2 (c - p) through the controller's stiffness. With the CoP the plan's, the
        angular-momentum objective asks for nothing: the trunk has no reason to pitch."""
        plan, gait = self.plan, self.config.gait
        n_plan = plan.foot.size
        roll_m = 0.0 if gait is None else gait.roll_m
        for r, sim in enumerate(ids):
            j = self.next_planned[sim]
            swinging = self.swing[sim] >= 0
            recovering = self.recovering[sim]
            if (recovering and not swinging) or (not self.planned[sim] and swinging and not recovering):
                continue  # a reactive step of no push on a plan (its Bezier), or between reactive steps (the task's)
            centers = 0.5 * (point_x[r, 0::2] + point_x[r, 1::2])  # the feet now
            feet = centers.copy()
            # (anchor: the stance foot's centre, length s from now on, anchor roll m, s since the segment began)
            segments = []
            walking = False
            landed = np.isfinite(self.last_touchdown_s[sim])  # a segment after a touchdown rolls (not the first)
            since = time_s - self.last_touchdown_s[sim] if landed else 0.0
            if swinging:  # the planned step j - 1 under way: its stance foot is the anchor
                left_s = max(self.duration_s[sim] - (time_s - self.t0[sim]), 0.0)
                forward = self.target_heel_x[sim] + self.heel_to_center_m - self.pivot_x[sim] > self.config.min_step_m
                segments.append((self.pivot_x[sim], left_s, roll_m * (forward and landed), since))
                walking = self.direction[sim] > 0  # the step under way is not a step back: the pattern holds
                feet[self.swing[sim]] = self.target_heel_x[sim] + self.heel_to_center_m
            for k in range(j, n_plan if not recovering else j):  # a reactive step: the capture point to rest
                stance = feet[1 - (plan.foot[k] ^ self.mirrored[sim])]
                land = self.origin_x[sim] + plan.x_m[k] + self.plan_offset_m[sim]
                now = k == j and not swinging  # waiting for this lift-off now
                if now:
                    wait = max(float(self._due_s(np.array([sim]))[0]) - time_s, 0.0)
                else:
                    wait = plan.double_support_s if not np.isfinite(plan.start_s[k]) else 0.0
                forward = land - stance > self.config.min_step_m
                segments.append((stance, wait + plan.duration_s[k], roll_m * (forward and (landed or not now)),
                                 since if now else 0.0))
                walking = land - stance > -self.config.min_step_m if len(segments) == 1 else walking
                feet[plan.foot[k] ^ self.mirrored[sim]] = land
            if not segments:
                continue  # the plan is done: the task's own targets bring the body to rest
            omega = math.sqrt(GRAVITY_M_S2 / max(float(com_z[r]), 0.5))
            xi_end = 0.5 * (feet[0] + feet[1])  # at rest over the feet after the last step
            for anchor, length, roll, _ in reversed(segments[1:]):
                xi_end = _dcm_start(xi_end, anchor - roll, anchor + roll, length, omega)
            centre, length, roll, since = segments[0]
            rate = 2.0 * roll / max(since + length, 1e-3)  # the anchor rolls heel to toe over the whole segment
            anchor = centre - roll + rate * since
            xi_ref = _dcm_start(xi_end, anchor, centre + roll, length, omega)
            if cmrt is not None:  # anticipation: the CMRT displaces the plan's capture point (its d + d' / omega)
                xi_ref += float(cmrt[0][r]) + float(cmrt[1][r]) / omega
            xi = com_x[r] + vel_x[r] / omega
            self.dcm_error_m[sim] = xi - xi_ref
            down = (contact[r, 0::2] | contact[r, 1::2]) & ~(np.arange(2) == self.swing[sim])
            if not down.any():
                continue
            lo = min(point_x[r, 2 * f] for f in range(2) if down[f])
            hi = max(point_x[r, 2 * f + 1] for f in range(2) if down[f])
            cop = float(np.clip(anchor + (1.0 + DCM_GAIN) * (xi - xi_ref), lo, hi))
            if swinging and not recovering and time_s - self.t0[sim] <= 0.5 * self.duration_s[sim]:
                # a push: the capture point's error, grown to touchdown, moves this step's landing (the plan's
                # later steps are where they were: the capture-point plan reaches them from the new footprint)
                error_td = (xi - xi_ref) * math.exp(omega * length)
                pivot = self.pivot_x[sim]
                planned = self.origin_x[sim] + plan.x_m[j - 1] + self.plan_offset_m[sim]
                landing = np.clip(planned + step_adjustment_m(error_td), pivot - self.config.max_back_step_m,
                                  pivot + self.config.max_step_m)
                self.target_heel_x[sim] = landing - self.heel_to_center_m
            accel = omega * omega * (com_x[r] - cop)
            command.com_ref_x_m[r] = com_x[r] + accel / plan.com_stiffness
            command.com_ref_vel_x_m_s[r] = vel_x[r]
            command.cop_x_m[r] = cop
            if gait is not None and walking and landed:  # from the first touchdown: a start is not a gait cycle
                command.swing_target[r, kernel.S_GAIT] = gait.momentum_gain

    def _gait_height(self, command: StepCommand, ids: np.ndarray, s: np.ndarray, phase: np.ndarray) -> None:
        """The CoM's height along a walking plan (``GaitPattern``), into ``command``: a forward step goes from its
        height at lift-off toward the walking height (standing less ``height_drop_m``) with a ``vault_m`` bell over
        the stance leg; a step closing the feet rises back to the standing height; the double support between steps
        holds the height of the touchdown."""
        gait, c = self.config.gait, self.config
        if gait is None:
            return
        target = command.swing_target
        swing = self.swing[ids]
        reach = np.abs(self.target_heel_x[ids] + self.heel_to_center_m - self.pivot_x[ids])
        walking_z = self.standing_z[ids] - gait.height_drop_m * np.minimum(1.0, (reach / gait.height_drop_step_m) ** 2)
        rows = np.flatnonzero((swing >= 0) & self.planned[ids] & (self.direction[ids] > 0)
                              & np.isfinite(self.last_touchdown_s[ids]))
        if rows.size:
            sims = ids[rows]
            T = self.duration_s[sims]
            phi, dphi, ddphi, h, dh, ddh = swing_profile(s[rows], c.width)
            closing = self.target_heel_x[sims] + self.heel_to_center_m - self.pivot_x[sims] <= c.min_step_m
            z0 = self.com0_z[sims]
            z1 = np.where(closing, self.standing_z[sims], np.minimum(z0, walking_z[rows]))
            vault = np.where(closing, 0.0, gait.vault_m)
            late = phase[rows] > 1.0  # not down yet: hold the step's end
            target[rows, kernel.S_HEIGHT] = np.where(late, z1, z0 + (z1 - z0) * phi + vault * h)
            target[rows, kernel.S_HEIGHT + 1] = np.where(late, 0.0, ((z1 - z0) * dphi + vault * dh) / T)
            target[rows, kernel.S_HEIGHT + 2] = np.where(late, 0.0, ((z1 - z0) * ddphi + vault * ddh) / T**2)
            target[rows, kernel.S_HEIGHT + 3:kernel.S_HEIGHT + 6] = (gait.height_weight, gait.height_k, gait.height_d)
        between = np.flatnonzero((swing < 0) & np.isfinite(self.last_touchdown_s[ids]) & self.planned[ids]
                                 & (self.next_planned[ids] < self.plan.foot.size))
        if between.size:
            target[between, kernel.S_HEIGHT] = np.minimum(self.touchdown_z[ids[between]], walking_z[between])
            target[between, kernel.S_HEIGHT + 1:kernel.S_HEIGHT + 3] = 0.0
            target[between, kernel.S_HEIGHT + 3:kernel.S_HEIGHT + 6] = (gait.height_weight, gait.height_k,
                                                                        gait.height_d)

    def _command(self, ids: np.ndarray, s: np.ndarray, phase: np.ndarray) -> StepCommand:
        c = self.config
        k = ids.size
        swing = self.swing[ids]
        target = np.zeros((k, kernel.N_SWING))
        com_ref = np.full(k, np.nan)
        com_vel = np.full(k, np.nan)
        rows = np.flatnonzero(swing >= 0)
        if rows.size:
            sims = ids[rows]
            T = self.duration_s[sims]
            sr = s[rows]
            phi, dphi, ddphi, h, dh, ddh = swing_profile(sr, c.width)
            dist = self.target_heel_x[sims] - self.start_heel_x[sims]
            target[rows, 0] = self.start_heel_x[sims] + dist * phi
            target[rows, 3] = dist * dphi / T
            target[rows, 6] = dist * ddphi / T**2
            target[rows, kernel.S_SWING_GAINS:kernel.S_SWING_GAINS + 3] = (c.swing_weight, c.swing_k, c.swing_d)
            heel_first = np.flatnonzero(self.heel_first[sims])
            if heel_first.size:  # toe-up over the swing's second half (a smoothstep), to land heel first
                target[rows[heel_first], 2], target[rows[heel_first], 5], target[rows[heel_first], 8] = (
                    v * scale for v, scale in zip(_toe_up(sr[heel_first]), (-c.heel_strike_rad,
                                                  -c.heel_strike_rad / T[heel_first],
                                                  -c.heel_strike_rad / T[heel_first] ** 2), strict=True))
            late = phase[rows] > 1.0  # not down yet: aim a few millimetres into the floor, gently
            target[rows, 1] = np.where(late, -0.005, c.lift_m * h)
            target[rows, 4] = np.where(late, 0.0, c.lift_m * dh / T)
            target[rows, 7] = np.where(late, 0.0, c.lift_m * ddh / T**2)
            target[rows, 9] = np.where(self.direction[sims] > 0, c.knee_bend_rad, c.back_knee_bend_rad)
            # a planned step crouches as much as its reach needs (feet brought together need none: the full bend
            # pushed the body up at their touchdown, 2.75 BW)
            target[rows, 9] *= np.where(self._plan_shaped(sims), self._crouch_scale(sims), 1.0)
            # a reactive step forward bends the stance knee as its foot travels: bent at once, the hip came down
            # onto a foot still ~1 mm up, pressed it into the floor (60 N on a foot the plan had unloaded), dragged
            # it forward and threw the CoP to the stance toe at lift-off. A planned step's crouch is scaled to its
            # reach already; a step back needs its 7 cm drop early (ramped, it landed at 2.7 body weights, not 2.4)
            target[rows, 9] *= np.where((self.direction[sims] > 0) & ~self.planned[sims], phi, 1.0)
            if self.plan is not None:  # a plan's forward swing knee bends (backward, it rolled the stance foot over
                # its toe at lift-off: a step back from standing fell)
                knee = swing_profile(np.minimum(sr / SWING_KNEE_UNTIL, 1.0), c.width)[3]
                target[rows, 10] = np.where(self._plan_shaped(sims) & (self.direction[sims] > 0),
                                            SWING_KNEE_BEND_RAD * np.where(late, 0.0, knee), 0.0)
            pivot = self.pivot_x[sims]
            mid = 0.5 * (pivot + self.target_heel_x[sims] + self.heel_to_center_m)
            b, db = bezier(sr, self.com0_x[sims], pivot, mid)
            com_ref[rows] = b
            com_vel[rows] = np.where(late, 0.0, db / T)
        settled = np.flatnonzero((swing < 0) & np.isfinite(self.last_touchdown_s[ids]))
        target[settled, kernel.S_SETTLED] = 1.0  # both feet down after a step: stand over them
        target[settled, kernel.S_STANCE:kernel.S_STANCE + 6] = self.stance_offsets[ids[settled]]
        landed = settled[self.heel_first[ids[settled]]]
        if landed.size:  # the foot that landed heel first lowers its toe to the floor
            target[landed, kernel.S_LANDING] = [self.footprints[sim][-1][0] + 1.0 for sim in ids[landed]]
            target[landed, kernel.S_LANDING + 1:kernel.S_LANDING + 5] = (c.landing_pitch_rad, c.landing_weight,
                                                                          c.landing_k, c.landing_d)
        return StepCommand(swing.astype(float), target, com_ref, com_vel,
                           None if self.plan is None else np.full(k, np.nan), self._arms(ids, s, rows))

    def _arms(self, ids: np.ndarray, s: np.ndarray, rows: np.ndarray) -> np.ndarray | None:
        """The plan's arm swing of rows ``ids`` (k, 3, 2): held between steps, along the foot's path during one."""
        if self.plan is None:
            return None
        arms = np.zeros((ids.size, 3, 2))
        arms[:, 0] = self.arm_to_rad[ids]
        planned = rows[self.planned[ids[rows]]]
        if planned.size:
            sims = ids[planned]
            phi, dphi, ddphi = swing_profile(s[planned], self.config.width)[:3]
            T = self.duration_s[sims][:, None]
            span = self.arm_to_rad[sims] - self.arm_from_rad[sims]
            arms[planned, 0] = self.arm_from_rad[sims] + span * phi[:, None]
            arms[planned, 1] = span * dphi[:, None] / T
            arms[planned, 2] = span * ddphi[:, None] / T**2
        return arms

    def support(self, ids: np.ndarray, point_x: np.ndarray, lo: np.ndarray, hi: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        """The support of the moment: the stance foot's [heel, toe] while the other swings (``lo``/``hi``
        elsewhere)."""
        return stance_support(self.swing[ids], point_x, lo, hi)

    def landing_span(self, ids: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For the balance monitor: a capture point over the footprint a swing foot is heading for is not a
        fall, so the support of a stepping clip includes that footprint."""
        return with_landing(self.swing[ids], self.target_heel_x[ids], self.foot_length_m, lo, hi)

    def step_reach_span(self, ids: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For the balance monitor: while no foot swings, a capture point one step can reach is not yet a fall (the
        body is one-step capturable, Koolen et al. 2012). The supervisor decides from the delayed state, so the
        capture point of a hard push leaves the feet before the foot lifts; a step then catches it, or the capture
        point runs past the step's reach too (a fall)."""
        idle = self.swing[ids] < 0
        c = self.config
        return np.where(idle, lo - c.max_back_step_m, lo), np.where(idle, hi + c.max_step_m, hi)

    def swinging(self, ids: np.ndarray) -> np.ndarray:
        """(k, 2) bool: which foot of each simulation swings now."""
        return swinging_feet(self.swing[ids])


def stance_support(swing: np.ndarray, point_x: np.ndarray, lo: np.ndarray, hi: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Copies of ``lo``/``hi`` with the stance foot's [heel, toe] (from ``point_x`` (k, 4)) in the rows whose
    ``swing`` (k,) foot is up."""
    rows = np.flatnonzero(swing >= 0)
    lo, hi = lo.copy(), hi.copy()
    if rows.size:
        stance = 1 - swing[rows]
        lo[rows] = point_x[rows, 2 * stance]
        hi[rows] = point_x[rows, 2 * stance + 1]
    return lo, hi


def with_landing(swing: np.ndarray, target_heel_x: np.ndarray, foot_length_m: float, lo: np.ndarray,
                 hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[lo, hi] widened, in the rows whose foot swings, to the footprint its heel is heading for."""
    stepping = swing >= 0
    return (np.where(stepping, np.fmin(lo, target_heel_x), lo),
            np.where(stepping, np.fmax(hi, target_heel_x + foot_length_m), hi))


def swinging_feet(swing: np.ndarray) -> np.ndarray:
    """(k, 2) bool from ``swing`` (k,): which foot swings."""
    return np.stack([swing == 0, swing == 1], axis=1)
