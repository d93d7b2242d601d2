"""Clips -> trajectories (CoM, CoP, support, contacts, balance loss), many at once.

``simulate_batch`` steps n clips of one task that differ only in their CMRT in lockstep
on ``mujoco.batch.Batch`` with one vectorised controller - one group of clips per core, each
group in its own thread (docs/performance.md) - and, for a scoring run, one compiled call per
control step (``cmrt.sim.tick``); ``simulate`` is the case n = 1. MuJoCo's batch is bit-identical
to stepping each simulation alone, and the controller's arithmetic is row-wise, so a candidate's objective does not
depend on what else is in its batch (tested).

A simulated clip is the task's clip (preparation P + task T + decay D = L) followed by
a standing tail of ``tail_s`` (the end pose held, no CMRT): the paper's objective only
looks at [0, L]; the tail shows whether the character really comes to rest.
It always starts from the task's settled standing state (the start pose held by the
controller for ``SETTLE_S`` seconds), so no start-up transient enters the objective.

Every control step the balance monitor (``cmrt.sim.balance``) checks for a loss of
balance. When it finds one, a scoring run stops that simulation (nothing after a fall
enters the score); a recorded run (``record=True``: traces, renders) switches it to a
protective mode - a passive spring-damper holding the pose it fell in, which cannot
add energy - and lets the topple play out to the end of the clip and tail, at least
``POST_FALL_S`` past the fall.

The CoP is measured from the contact forces MuJoCo applied during each step: touch
sensors around the four heel/toe spheres read each point's normal force f_i, the
contact lies straight under the sphere's centre x_i, so ``cop_x = sum f_i x_i / sum f_i``.
Forces on the hands (a ball, a bag, a slab) never enter it.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import mujoco
import mujoco.batch
import numpy as np

from cmrt.body.character import FOOT_POINT_RADIUS_M, character
from cmrt.body.floating_box import FloatingBox, contact_wrench
from cmrt.body.props import CONTACT_FORCE_N, model_values, prop_class
from cmrt.body.stance import leg_offsets
from cmrt.body.surface import Support, body_inertia_yy, frame_field, lean_rate, lean_x, tilt_pose, uniform_field
from cmrt.control import ControllerConfig, MomentumBalanceController
from cmrt.control.compiled import note_first_compile
from cmrt.control.controller import read_only
from cmrt.control.gait import GaitTracker, KeyedSwings
from cmrt.control.planar import PlanarKinematics
from cmrt.control.references import MotionCom, Targets, YuReference, motion_com
from cmrt.control.stepping import MOMENTUM, StepCommand, StepConfig, StepPlan, StepSupervisor
from cmrt.errors import CmrtError
from cmrt.motion.curve import Cmrt
from cmrt.motion.ensemble import NOMINAL, Perturbation
from cmrt.motion.footsteps import DOUBLE_SUPPORT_S, FIRST_STEP_S
from cmrt.motion.gait import feet_paths, stand_frame
from cmrt.motion.task import Task
from cmrt.sim.balance import REASONS, BalanceLimits, FallReason, capture_point_x
from cmrt.sim.monitor import FallMonitor, ProtectiveMode
from cmrt.sim.tick import control_tick, geometry, sample_support

SETTLE_S = 1.5
POST_FALL_S = 1.0  # a recorded clip runs at least this long past a fall, so the topple is seen
CONTACT_HEIGHT_M = 0.001  # a heel/toe point whose lowest point is below this height touches the floor
# Scoring runs in the center mode with feet planted do their control steps in one compiled call
# (cmrt.sim.tick); False runs them on the Python path, as traces do (tests compare the two bit for bit).
COMPILED_TICK = True
# ...and step the batch through MuJoCo's bound C++ ``step`` (see ``direct_step``); False: ``Batch.step``.
DIRECT_STEP = True
CONTROL_FIELDS = ("qpos", "qvel", "cdof", "cdof_dot", "cvel", "cinert", "M", "qfrc_bias", "qfrc_passive",
                  "subtree_com", "xpos", "geom_xpos")
STATE_FIELDS = ("qpos", "qvel", "qacc_warmstart")


@dataclass(frozen=True)
class Trajectory:
    """Per-physics-step record of a clip and its tail; time-aligned arrays (n_steps, ...).

    Without ``record`` only what the score needs is filled (CoP, support, the humanoid's
    joint angles and CoM at the CoP sample steps; ground force every step; joint speed,
    CoM and controls at control steps); the rest is NaN. Arrays end where the
    simulation stopped: the end of the tail, or the fall when scoring."""

    time_s: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    com_m: np.ndarray  # (n, 2): x, z
    com_vel_x_m_s: np.ndarray
    capture_point_x_m: np.ndarray
    cop_x_m: np.ndarray  # measured from the contact forces; NaN when the feet carry no load
    support_center_x_m: np.ndarray
    support_lo_x_m: np.ndarray
    support_hi_x_m: np.ndarray
    normal_force_n: np.ndarray  # total vertical ground force on the feet, every step
    foot_normal_force_n: np.ndarray  # (n, 2): right, left
    point_normal_force_n: np.ndarray  # (n, 4): heel_r, toe_r, heel_l, toe_l (the CoP sample steps): where each foot's
    # own CoP is (its toe's share of its load, heel 0 to toe 1)
    point_lift_m: np.ndarray  # (n, 4): heel_r, toe_r, heel_l, toe_l above settled height
    point_contact: np.ndarray  # (n, 4): 1 where that point touches the floor (control steps), else 0
    foot_roll_rad: np.ndarray  # (n, 2): pitch of each foot (0 flat; < 0 toes up)
    prop_force_n: np.ndarray  # force between the character and the task's prop, every step (NaN: no prop)
    max_joint_speed_rad_s: np.ndarray  # largest |qvel| of the actuated joints (control steps)
    cmrt_displacement_m: np.ndarray
    com_ref_x_m: np.ndarray  # the controller's reference CoM, CMRT included (control steps; held between them)
    cop_ref_x_m: np.ndarray  # its reference CoP (the support centre, or Yu's eq. 3.4): at the CoP sample steps
    ctrl_nm: np.ndarray  # (n, nu): the torques applied during the step (control steps; every step in traces)
    plan_cop_x_m: np.ndarray  # the CoP the controller planned for them (control steps of traces; NaN: no plan,
    # protective mode, a foot swinging)
    lowest_body_z_m: np.ndarray  # lowest point of a body other than the feet above the floor (traces)
    protective: np.ndarray  # (n,) bool: torques came from the protective mode (after a fall)
    clip_s: float  # L: the end of the scored clip; the standing tail follows
    fell: bool
    fall_time_s: float | None
    fall_reason: FallReason | None
    diverged: bool
    final_qpos: np.ndarray  # the humanoid's at the end of the tail, or at the fall
    final_com_speed_m_s: float  # |CoM velocity| at the end of the tail, or at the fall
    task_success: bool | None = None  # goal reached (ball caught and held, slab toppled, pad struck)
    step_times_s: tuple[float, ...] = ()  # lift-off of every step the supervisor took (stepping tasks)
    footprints: tuple[tuple[int, float, float], ...] = ()  # (foot 0 right / 1 left, touchdown s, heel x m)
    flat_times_s: tuple[float, ...] = ()  # when a landed foot first stood on both its points (a heel-first landing's
    # second contact: ``cmrt.control.stepping.LandingWatch``)
    prop_extras: dict[str, float] = field(default_factory=dict)  # e.g. grip_s, ball_sag_m for a ball
    fall_capture_point_x_m: float | None = None  # at the fall (the direction of a fall not played out)
    fall_com_vel_x_m_s: float | None = None
    footstep_errors_m: tuple[float, ...] = ()  # landed - planned centre of each planned step that landed before
    # any fall (a footstep plan: Task.steps)
    support_pose: np.ndarray | None = None  # (n, 3): the support frame's world tilt (rad), x, z (m); None: a
    # still level floor (a floating box's pose is known only from its run: pictures take it from here)
    push_n: np.ndarray | None = None  # (n,): the horizontal push on the thorax at every step (the task's and an
    # ensemble member's; the controller does not know it); None: no push

    @property
    def max_lift_m(self) -> float:
        """Highest any heel/toe point rose above its settled height (m): a planted foot should not lift."""
        lift = self.point_lift_m[np.isfinite(self.point_lift_m).all(axis=1)]
        return float(lift.max()) if lift.size else 0.0

    def as_npz_dict(self) -> dict[str, np.ndarray]:
        """The arrays ``--trace`` saves."""
        out = {k: v for k, v in self.__dict__.items() if isinstance(v, np.ndarray)}
        for key in ("fell", "diverged", "clip_s", "final_com_speed_m_s"):
            out[key] = np.array(getattr(self, key))
        out["fall_time_s"] = np.array(np.nan if self.fall_time_s is None else self.fall_time_s)
        for key in ("fall_capture_point_x_m", "fall_com_vel_x_m_s"):
            out[key] = np.array(np.nan if getattr(self, key) is None else getattr(self, key))
        out["fall_reason"] = np.array("" if self.fall_reason is None else self.fall_reason.value)
        out["task_success"] = np.array(np.nan if self.task_success is None else float(self.task_success))
        out.update({k: np.array(v) for k, v in self.prop_extras.items()})
        out["step_times_s"] = np.array(self.step_times_s, float)
        out["footprints"] = np.array(self.footprints, float).reshape(-1, 3)
        out["footstep_errors_m"] = np.array(self.footstep_errors_m, float)
        out["flat_times_s"] = np.array(self.flat_times_s, float)
        return out


class _Geometry:
    """Constant per-model data for the balance checks."""

    def __init__(self):
        ch = character()
        m = ch.model
        self.points = np.array(ch.foot_point_geoms)  # heel_r, toe_r, heel_l, toe_l
        feet = set(ch.foot_point_geoms) | {ch.floor_geom}
        body = [g for g in range(m.ngeom) if g not in feet and m.geom_conaffinity[g] and m.geom_type[g]
                == mujoco.mjtGeom.mjGEOM_CAPSULE]
        self.body_geoms = np.array(body)
        self.radius = m.geom_size[body, 0]
        self.half = m.geom_size[body, 1]
        self.leg_dofs = np.array(ch.leg_dofs)
        self.root_pitch = ch.root_dofs[2]

    def lowest_body_z(self, geom_xpos: np.ndarray, geom_xmat: np.ndarray) -> np.ndarray:
        """Lowest point of any non-foot capsule, per simulation (numpy; the loop uses ``at_control``, which
        is tested against this)."""
        z = geom_xpos[:, self.body_geoms, 2] - np.abs(geom_xmat[:, self.body_geoms, 8]) * self.half - self.radius
        return z.min(axis=1)

    def at_control(self, geom_xpos, geom_xmat, qpos, qvel, act) -> tuple[np.ndarray, ...]:
        """``cmrt.sim.tick.geometry`` of these rows: point_x, lo, hi, contact, roll, jspeed, lowest, grounded, c_lo,
        c_hi (fresh arrays: the stepping supervisor and the records may keep them)."""
        n = qpos.shape[0]
        out = (np.empty((n, self.points.size)), np.empty(n), np.empty(n), np.empty((n, self.points.size), bool),
               np.empty((n, 2)), np.empty(n), np.empty(n), np.empty(n, bool), np.empty(n), np.empty(n))
        geometry(np.arange(n), (geom_xpos, geom_xmat, qpos, qvel), (self.points, self.body_geoms, self.half,
                 self.radius, self.leg_dofs, self.root_pitch, act, FOOT_POINT_RADIUS_M, CONTACT_HEIGHT_M), out)
        return out

    def foot_roll(self, qpos: np.ndarray) -> np.ndarray:
        """(n, 2) foot pitch: root pitch plus the leg's hip, knee and ankle angles."""
        return qpos[:, self.root_pitch, None] + qpos[:, self.leg_dofs].sum(axis=2)


_SETTLED: dict = {}
PLANTED_FORCE_N = 5.0  # a heel/toe point carrying less is not planted: a foot lifting off (0 N, within the contact
# distance for a few ms) moves forward without sliding (two 0.4 m steps of 0.4 s "slid" 2.4 cm that way), and a
# swing foot grazing the floor is no support


def thread_count(n: int) -> int:
    """Threads for a batch of ``n`` simulations: ``$CMRT_THREADS`` (default: the CPUs), at most ``n``."""
    return max(1, min(n, int(os.environ.get("CMRT_THREADS", os.cpu_count() or 1))))


def _in_contact(geom_xpos: np.ndarray, points: np.ndarray) -> np.ndarray:
    return geom_xpos[:, points, 2] - FOOT_POINT_RADIUS_M < CONTACT_HEIGHT_M


def settled_state(task: Task, config: ControllerConfig) -> dict[str, np.ndarray]:
    """The start pose after the controller held it for SETTLE_S (cached per process and model)."""
    support = Support.from_params(task.params)
    config = surface_config(config, task)
    q0 = task.start_qpos()
    if support.floating:  # the feet's centre over the deck's
        q0 = _centred(q0)
    # on a tilted support the start pose stands upright in the world; it settles in the field of t = 0, held
    static = replace(support, tilt_period_s=np.inf, sway_period_s=np.inf, heave_period_s=np.inf,
                     box_mass_kg=0.0)  # a floating box settles the character at rest on still water
    field = None if support.still_and_level else _SupportField(static, task.model(), character().model.nbody)
    q0 = tilt_pose(character().model, q0, float(support.tilt(0.0)[0]))
    key = (q0.tobytes(), config, task.prop, model_values(task.prop, task.params), static)
    if key not in _SETTLED:
        ch = character()
        m = task.model()
        prop = prop_class(task.prop)(m, task.params)
        batch = mujoco.batch.Batch(m, nsim=1, nthread=1, persistent=True)
        f = {k: batch.bind(k) for k in set(CONTROL_FIELDS) | set(STATE_FIELDS) | {"ctrl", "xipos", "xfrc_applied"}}
        f["qpos"][0, : q0.size] = q0
        f["qpos"][0, 1] -= 0.002  # start just in contact: the feet sink ~2 mm under body weight
        batch.forward(stage=mujoco.mjtStage.mjSTAGE_VEL)
        ctrl = MomentumBalanceController(ch, config)
        points = np.array(ch.foot_point_geoms)
        lo, hi = _support(f["geom_xpos"], points)
        center = 0.5 * (lo + hi)
        zeros = np.zeros(q0.size)
        for k in range(int(round(SETTLE_S / m.opt.timestep))):
            if field is not None:
                field.update(f, slice(None), 0.0)
                field.apply(f, slice(None), np.zeros(1), ch.thorax_body)
            if k % config.control_every == 0:
                contact = _in_contact(f["geom_xpos"], points)
                com_ref = center if field is None else center + static.lean_x(0.0, f["subtree_com"][:, 1, 2])
                f["ctrl"][:] = ctrl.torques(f, q0, zeros, zeros, com_ref, np.zeros(1), center, contact,
                                            field=None if field is None else field.for_controller()).torque_nm
            prop.settle_hold(f)
            batch.step(stage=mujoco.mjtStage.mjSTAGE_VEL)
        _SETTLED[key] = {k: f[k][0].copy() for k in STATE_FIELDS}
    return _SETTLED[key]


def _centred(qpos: np.ndarray) -> np.ndarray:
    """``qpos`` moved along x so that the feet's heel-to-toe span is centred on x = 0."""
    ch = character()
    d = mujoco.MjData(ch.model)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(ch.model, d)
    lo, hi = _support(d.geom_xpos[None], np.array(ch.foot_point_geoms))
    q = np.array(qpos, dtype=float)
    q[0] -= 0.5 * float(lo[0] + hi[0])
    return q


def _support(geom_xpos: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    xs = geom_xpos[:, points, 0]
    return xs.min(axis=1), xs.max(axis=1)


def _ground_support(contact: np.ndarray, point_x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per simulation: is any heel/toe point on the floor, and [lo, hi] spanned by the feet that touch it
    (NaN if none). A foot rolled onto its toe still spans heel to toe: a capture point between them brings
    it back down flat; only beyond the rolling edge is the body going over. (numpy; the loop uses
    ``_Geometry.at_control``, which is tested against this.)"""
    foot_down = contact[:, 0::2] | contact[:, 1::2]  # (n, 2): right, left
    on = np.repeat(foot_down, 2, axis=1)  # both points of a foot that touches
    grounded = foot_down.any(axis=1)
    lo = np.where(grounded, np.where(on, point_x, np.inf).min(axis=1), np.nan)
    hi = np.where(grounded, np.where(on, point_x, -np.inf).max(axis=1), np.nan)
    return grounded, lo, hi


def _judge_prop(prop, b, rows, force, times, windows, goal, extras) -> None:
    """The prop's verdict and figures for simulations ``rows`` as they are now (a fall freezes them, so
    a recorded topple cannot change them). ``windows`` (n, 2): each simulation's task window."""
    if rows.size == 0:
        return
    for window in np.unique(windows[rows], axis=0):
        same = np.all(windows[rows] == window, axis=1)
        verdict = prop.success(b, rows[same], force[same], times, tuple(window))
        if verdict is not None:
            goal[rows[same]] = verdict
    for key, values in prop.extras(b, rows).items():
        extras.setdefault(key, np.full(goal.size, np.nan))[rows] = values


@functools.cache
def _shoulder_dofs() -> tuple[int, int]:
    ch = character()
    return ch.dof("shoulder_r"), ch.dof("shoulder_l")


def _control(controller, f, refs, com_ref, com_ref_vel, cop_ref, contact, mass, step: StepCommand | None = None,
             warm: np.ndarray | None = None, ids: np.ndarray | None = None, load=None, field=None):
    """Torques and the planned CoP (``ControlOutput.cop_x_m``) for the given rows; a row whose plan is singular or
    non-finite gets zero torques, a NaN plan and bad=True. ``warm`` (all simulations, n_rows): the QPs' active
    sets (``ControllerConfig.warm_start``), read and updated at rows ``ids`` (a row whose plan is singular keeps
    its own, as the compiled tick does)."""
    if step is not None:
        com_ref, com_ref_vel = step.com_targets(com_ref, com_ref_vel)
        cop_ref = step.cop_target(cop_ref)
        refs = step.with_arms(refs, _shoulder_dofs())

    def swing(rows):
        return {} if step is None else {"swing_foot": step.swing_foot[rows], "swing_target": step.swing_target[rows]}

    # no np.errstate here: the compiled kernel raises no numpy FP warnings, and entering one per control
    # step cost more than a percent of an evaluation
    active = None if warm is None else warm[ids]
    try:
        out = controller.torques(f, *refs, com_ref, com_ref_vel, cop_ref, contact, mass, **swing(slice(None)),
                                 warm=active, load=load, field=field)
        ctrl, plan_cop = out.torque_nm, out.cop_x_m
        if warm is not None:
            warm[ids] = active
    except np.linalg.LinAlgError:  # find the culprits one by one; the others are unaffected
        ctrl = np.full((com_ref.size, controller.limits.size), np.nan)
        plan_cop = np.full(com_ref.size, np.nan)
        for i in range(com_ref.size):
            fi = {name: f[name][i : i + 1] for name in CONTROL_FIELDS}
            one = None if warm is None else warm[ids[i : i + 1]]
            refs_i = tuple(r[i : i + 1] if r.ndim == 2 else r for r in refs)
            try:
                out = controller.torques(fi, *refs_i, com_ref[i : i + 1], com_ref_vel[i : i + 1],
                                         cop_ref[i : i + 1], contact[i : i + 1], mass[i : i + 1],
                                         **swing(slice(i, i + 1)), warm=one,
                                         load=None if load is None else (load[0][i : i + 1], load[1][i : i + 1],
                                                                         load[2]),
                                         field=None if field is None else (field[0][i : i + 1], field[1][i : i + 1]))
                ctrl[i], plan_cop[i] = out.torque_nm[0], out.cop_x_m[0]
                if warm is not None:
                    warm[ids[i]] = one[0]
            except np.linalg.LinAlgError:
                pass
    bad = ~np.all(np.isfinite(ctrl), axis=1)
    ctrl[bad] = 0.0
    plan_cop = np.where(bad, np.nan, plan_cop)
    return ctrl, bad, plan_cop


class _Recorder:
    """Buffers (n, n_steps, ...) filled at the steps where each quantity is read; NaN elsewhere."""

    SHAPES = {"com": (2,), "com_vel": (), "xi": (), "cop": (), "sc": (), "lo": (), "hi": (), "fz": (),
              "ffz": (2,), "pfz": (4,), "lift": (4,), "contact": (4,), "roll": (2,), "jspeed": (), "cref": (),
              "pref": (), "plan_cop": (), "body_z": (), "ctrl": None, "prop_force": (),
              "qpos": None, "qvel": None}

    def __init__(self, n: int, n_steps: int, nq: int, nv: int, nu: int):
        sizes = {"ctrl": (nu,), "qpos": (nq,), "qvel": (nv,)}
        self.buf = {k: np.full((n, n_steps, *(sizes.get(k) if s is None else s)), np.nan)
                    for k, s in self.SHAPES.items()}

    def __getitem__(self, key: str) -> np.ndarray:
        return self.buf[key]

    def cut(self, i: int, last: int) -> dict[str, np.ndarray]:
        return {k: v[i, :last] for k, v in self.buf.items()}


@dataclass(frozen=True)
class _Drive:
    """What drives each simulation of a batch: its CMRT, its reference motion (computed once per distinct
    timing; rows index their variant), its thorax push, its prop mass and its task window."""

    disp_m: np.ndarray  # (n, steps): CMRT displacement d(t)
    disp_vel_m_s: np.ndarray  # (n, steps)
    q_ref: np.ndarray  # (steps, nv), or (variants, steps, nv) when the rows differ in timing
    qd_ref: np.ndarray
    qdd_ref: np.ndarray
    variant_of: np.ndarray | None  # (n,): each row's timing variant; None: one timing for all rows
    push_n: np.ndarray  # (n, steps): horizontal force on the thorax
    push_changes: np.ndarray  # (steps,): the push changes at this step (written to the batch only then)
    mass_scale: np.ndarray  # (n,): the prop's mass as a multiple of the task's
    windows_s: np.ndarray  # (n, 2): [P, P + T] of each row's timing
    motion_com: list[MotionCom] | None = None  # per timing variant: the reference's foot-to-CoM (yu mode only)

    def refs_at(self, k: int, rows) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Reference q, qd, qdd at step ``k`` for simulations ``rows``."""
        if self.variant_of is None:
            return self.q_ref[k], self.qd_ref[k], self.qdd_ref[k]
        v = self.variant_of[rows]
        return self.q_ref[v, k], self.qd_ref[v, k], self.qdd_ref[v, k]

    def foot_to_com_at(self, k: int, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The reference motion's foot-to-CoM x and its rate at step ``k``, (rows, 2) each (yu mode)."""
        v = np.zeros(rows.size, int) if self.variant_of is None else self.variant_of[rows]
        x = np.stack([mc.foot_to_com_x_m[k] for mc in self.motion_com])
        vel = np.stack([mc.foot_to_com_vel_x_m_s[k] for mc in self.motion_com])
        return x[v], vel[v]


def _drive(task: Task, curves: list[Cmrt], members: list[Perturbation], times: np.ndarray) -> _Drive:
    nv = character().nv
    scales = sorted({p.time_scale for p in members})
    variant_tasks = [Perturbation(time_scale=s).task_variant(task) for s in scales]
    variant_of = np.array([scales.index(p.time_scale) for p in members])
    variant_refs = [vt.reference(times) for vt in variant_tasks]
    if len(scales) == 1:
        q_ref, qd_ref, qdd_ref = variant_refs[0]
    else:
        q_ref, qd_ref, qdd_ref = (np.stack([r[i] for r in variant_refs]) for i in range(3))
    push = task.pushes_n(times)[None, :] + np.stack([p.push_at(times) for p in members])
    return _Drive(
        disp_m=np.stack([c.displacement_m(times) for c in curves]),  # zero after L
        disp_vel_m_s=np.stack([c.velocity_m_s(times) for c in curves]),
        q_ref=q_ref, qd_ref=qd_ref, qdd_ref=qdd_ref, variant_of=None if len(scales) == 1 else variant_of,
        push_n=push, push_changes=np.concatenate([[True], np.any(np.diff(push, axis=1) != 0, axis=0)]),
        mass_scale=np.array([p.prop_mass_scale for p in members]),
        windows_s=np.array([vt.task_window_s() for vt in variant_tasks])[variant_of],
        motion_com=[motion_com(character(), r[0][:, :nv], r[1][:, :nv]) for r in variant_refs]
        if task.reference_mode == "yu" else None,
    )


def surface_config(config: ControllerConfig, task: Task) -> ControllerConfig:
    """The controller's friction cone scaled with the floor's (its margin below MuJoCo's 1.0 kept)."""
    mu = Support.from_params(task.params).floor_friction
    return config if mu == 1.0 else replace(config, friction_coef=config.friction_coef * mu)


def _targets(yu: YuReference | None, b: dict, sel, ids: np.ndarray, drive: _Drive, k: int, center: np.ndarray,
             lo: np.ndarray, hi: np.ndarray, com: np.ndarray, com_vel_x: np.ndarray, nb: int,
             lean_x: np.ndarray | None = None) -> Targets:
    """The controller's reference CoM (CMRT included), its rate and the reference CoP of simulations ``ids``
    (batch rows ``sel``) at step ``k``, in the task's reference mode (``cmrt.control.references``)."""
    if yu is None:  # center: the support centre (Macchietto; ABC)
        return Targets(center + drive.disp_m[sel, k], drive.disp_vel_m_s[sel, k], center)
    touch = b["sensordata"][sel, :4]  # the last step's normal force at heel_r, toe_r, heel_l, toe_l
    rel, rel_vel = drive.foot_to_com_at(k, ids)
    return yu.targets(foot_force_n=np.stack([touch[:, 0] + touch[:, 1], touch[:, 2] + touch[:, 3]], axis=1),
                      ankle_xz=b["xpos"][sel][:, yu.feet][:, :, [0, 2]], foot_to_com_x=rel, foot_to_com_vel_x=rel_vel,
                      disp_m=drive.disp_m[sel, k], disp_vel_m_s=drive.disp_vel_m_s[sel, k], com=com,
                      com_vel_x=com_vel_x, cinert=b["cinert"][sel, :nb], support_lo_x=lo, support_hi_x=hi,
                      lean_x=lean_x)


def _delayed(targets: Targets, delay_steps: int, k: int, ids: np.ndarray, com_x_m: np.ndarray,
             com_vel_x_m_s: np.ndarray, rec_com: np.ndarray, fb_vel: np.ndarray) -> Targets:
    """The targets as the delayed balance feedback acts on them (``ControllerConfig.feedback_delay_s``): the
    kernel's ``k_l m (c_r - c) + d_l (m c_r' - L)`` then sees the CoM of ``delay_steps`` ago, c(t - tau), while the
    plan's dynamics and contact rows use the state of now (docs/controller.md). Before the clip's first
    ``delay_steps`` the character stood still: the first control step stands in for them."""
    if delay_steps == 0:
        return targets
    kd = max(k - delay_steps, 0)
    return Targets(targets.com_x_m + (com_x_m - rec_com[ids, kd, 0]),
                   targets.com_vel_x_m_s + (com_vel_x_m_s - fb_vel[ids, kd]), targets.cop_x_m)


def _torques(controller: MomentumBalanceController, b: dict, sel, ids: np.ndarray, fallen: np.ndarray,
             drive: _Drive, k: int, targets: Targets, contact: np.ndarray, mass: np.ndarray,
             nu: int, step: StepCommand | None = None,
             warm: np.ndarray | None = None, prop=None, field=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Torques of simulations ``ids`` (batch rows ``sel``): the controller for those standing, protective
    mode for those that fell. ``bad``: the controller's plan was singular or non-finite; ``plan_cop``: the CoP
    it planned (NaN in protective mode or for a bad plan). ``targets``: the
    reference CoM/CoP of rows ``ids`` (``_targets``); ``step``: the stepping supervisor's command for rows
    ``ids`` (None: feet planted)."""
    t = targets
    if not fallen.any():  # everyone under control: the bound arrays themselves, no copies
        f = b if isinstance(sel, slice) else {name: b[name][sel] for name in CONTROL_FIELDS}
        load = None if prop is None else prop.hand_load(b, ids)
        return _control(controller, f, drive.refs_at(k, ids), t.com_x_m, t.com_vel_x_m_s, t.cop_x_m, contact,
                        mass[sel], step, warm, ids, load, field)
    ctrl = np.zeros((ids.size, nu))
    bad = np.zeros(ids.size, bool)
    plan_cop = np.full(ids.size, np.nan)
    if not fallen.all():
        up = np.flatnonzero(~fallen)
        rows = ids[up]
        f = {name: b[name][rows] for name in CONTROL_FIELDS}
        ctrl[up], bad[up], plan_cop[up] = _control(
            controller, f, drive.refs_at(k, rows), t.com_x_m[up], t.com_vel_x_m_s[up], t.cop_x_m[up], contact[up],
            mass[rows], None if step is None else step.rows(up), warm, rows,
            None if prop is None else prop.hand_load(b, rows), None if field is None else (field[0][up], field[1][up]))
    return ctrl, bad, plan_cop  # the fallen: motors off, their joints passive (``ProtectiveMode``)


def direct_step(batch: mujoco.batch.Batch, stage: mujoco.mjtStage):
    """``step(ids32)``: ``batch.step(ids, stage=stage)`` without the checks ``Batch.step`` makes of its ids
    on every call (dtype, order, uniqueness, range: 5 us, as much Python as the rest of a lean step), for
    ids the scoring loop validated once when they changed - sorted, unique, in range, int32 - or None for
    all rows. It calls the C++ batch ``Batch.step`` itself wraps (the private ``_b``), so the simulation is
    the same call (tests/sim/test_tick.py compares the two bit for bit and checks this path is taken with
    the installed MuJoCo); a MuJoCo without it gets the public ``Batch.step``. 11 % of the seed-1
    optimization's evaluation time on 2 cores (docs/performance.md)."""
    raw = getattr(getattr(batch, "_b", None), "step", None)
    check = getattr(batch, "_check", None)
    if not DIRECT_STEP or raw is None or check is None:
        return lambda ids32: batch.step(ids=ids32, stage=stage)
    stage_int = int(stage)

    def step(ids32: np.ndarray | None) -> None:
        failed = raw(ids32, 1, stage_int)
        if failed:  # a simulation MuJoCo could not step: Batch.step's own error
            check(ids32, failed)

    return step


def _ground_records(rec: _Recorder, touch: np.ndarray, sample_x: np.ndarray, sample_every: int,
                    control_every: int) -> None:
    """The ground-force records of the steps a compiled scoring loop ran, from its per-step heel/toe forces
    ``touch`` (n, k, 4; a row's readings past its last step are cut off later) and heel/toe x at the control and
    sample steps: the same sums, in the same order, as the Python loop makes step by step (numpy sums four terms
    one by one). The CoP is measured at both; the rest at the sample steps."""
    k = touch.shape[1]
    fz = touch.sum(axis=2)
    rec["fz"][:, :k] = fz
    read = np.union1d(np.arange(0, k, sample_every), np.arange(0, k, control_every))
    with np.errstate(all="ignore"):
        rec["cop"][:, read] = np.where(fz[:, read] > 1e-9, (touch[:, read] * sample_x[:, read]).sum(axis=2)
                                       / fz[:, read], np.nan)
    samples = np.arange(0, k, sample_every)
    t = touch[:, samples]
    rec["ffz"][:, samples, 0] = t[:, :, :2].sum(axis=2)
    rec["ffz"][:, samples, 1] = t[:, :, 2:].sum(axis=2)
    rec["pfz"][:, samples] = t


@functools.lru_cache(maxsize=64)
def _no_held(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Nothing held that the character's bodies do not carry (``Prop.held_mass``), for the compiled tick."""
    return np.zeros(n), np.zeros((n, 2)), np.zeros(n), np.zeros(n)


@functools.lru_cache(maxsize=64)
def _no_load(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """No load on the hands (``Prop.hand_load``), for the compiled tick's arguments, made once per n: writable like
    a prop's load (the kernel only reads them; another array type would compile the tick a second time)."""
    return np.zeros((n, 2)), np.zeros((n, 3)), np.zeros(0, np.int64)


class _SupportField:
    """The support's field on every body of a batch (``cmrt.body.surface``; None on a still level floor): made
    once per physics step from the state the step starts from, applied by MuJoCo in that step (with the thorax
    push, which it would otherwise overwrite) and known to the controller on a control step. On a floating box
    (``cmrt.body.floating_box``) each simulation's box is advanced here first, from the contact load of the step
    before; its tilt per step is kept (``tilt_at``: the controller feels it with the feedback delay)."""

    def __init__(self, support: Support, m: mujoco.MjModel, nb: int, n: int = 1, n_steps: int = 1,
                 delay_steps: int = 0):
        self.support = support
        self.mass_kg = m.body_mass.copy()
        self.inertia_yy = body_inertia_yy(m)
        self.rootid = m.body_rootid.copy()
        self.nb = nb  # the humanoid's bodies: what the controller knows of
        self.force = self.xipos = None
        self.box: FloatingBox | None = None
        self.dt = m.opt.timestep
        # the support frame's world pose (theta, x, z) per step (a floating box's is known only as it happens)
        self.pose = np.full((n, n_steps, 3), np.nan) if support.floating else None
        self.omega = np.full((n, n_steps), np.nan) if support.floating else None
        self.anchor = None  # the root's position (support x, z) in the step before: the box's load is about it
        self.delay_steps = delay_steps  # the feedback delay: how late the controller feels a box's tilt
        self.known = None

    def update(self, b: dict, sel, t_s: float, ids: np.ndarray | None = None, k: int = 0,
               fallen: np.ndarray | None = None) -> None:
        self.xipos = b["xipos"][sel]
        cvel = b["cvel"][sel]
        r = self.xipos - b["subtree_com"][sel][:, self.rootid]  # cvel is about the tree's own CoM
        w = cvel[..., 1]
        vel = np.stack([cvel[..., 3] + w * r[..., 2], cvel[..., 5] - w * r[..., 0]], axis=-1)
        if not self.support.floating:
            self.force = self.support.field(t_s, self.xipos[..., [0, 2]], vel, self.mass_kg, self.inertia_yy)
            return
        ids = np.arange(self.xipos.shape[0]) if ids is None else ids
        body = slice(1, self.nb)  # the humanoid as a rigid body (the world body has no mass)
        mass = self.mass_kg[body].sum()
        com = b["subtree_com"][sel][:, 1, [0, 2]]
        rel = self.xipos[:, body][..., [0, 2]] - com[:, None]
        inertia_com = (self.inertia_yy[body] + self.mass_kg[body] * (rel ** 2).sum(axis=-1)).sum(axis=1)
        if self.box is None:  # the water's damping is a ratio of the critical damping of the loaded box at rest
            about_deck = float(inertia_com[0] + mass * (com[0] ** 2).sum())
            self.box = FloatingBox(self.pose.shape[0], self.support.box_mass_kg, self.support.box_stiffness_n_m,
                                   self.support.box_damping_ratio, mass, about_deck, self.dt)
        if k > 0:  # the contact load of the step just taken moves the box (none before the first step)
            wrench = contact_wrench(b["qfrc_constraint"][sel][:, :3], self.anchor[ids])
            self.box.advance(ids, wrench, np.full(ids.size, mass), com, inertia_com)
            if fallen is not None and fallen.any():
                # A topple played out for the pictures: the box is held where it was. A body lying beyond the
                # 1 m deck would load an infinite one (the floor plane), and a light box then flips over.
                self.box.hold(ids[fallen])
        else:
            self.anchor = np.zeros((self.pose.shape[0], 2))
        self.anchor[ids] = b["xpos"][sel][:, 1, [0, 2]]
        theta, omega, alpha, acc = self.box.frame(ids)
        self.pose[ids, k, 0], self.pose[ids, k, 1:] = theta, self.box.q[ids, :2]
        self.omega[ids, k] = omega
        ux, uz = uniform_field(theta, acc)
        self.force = frame_field(omega[:, None], alpha[:, None], ux[:, None], uz[:, None], self.xipos[..., [0, 2]],
                                 vel, self.mass_kg, self.inertia_yy)
        # What the controller knows of it: gravity along the deck as tilted ``delay_steps`` ago (felt, like the
        # CoM it balances), not the box's acceleration - that follows from the controller's own forces one step
        # before, and planning against it closes a loop the box's pitch then swings in (measured: a still stand
        # on 200 kg, 9.81 kN/m rocked +-7 degrees and fell at 8.8 s; with the felt tilt it settles at 3 degrees).
        felt = uniform_field(self.pose[ids, max(k - self.delay_steps, 0), 0], np.zeros_like(acc))
        still = np.zeros((ids.size, 1))
        self.known = frame_field(still, still, felt[0][:, None], felt[1][:, None], self.xipos[..., [0, 2]], vel,
                                 self.mass_kg, self.inertia_yy)

    def apply(self, b: dict, sel, push_n: np.ndarray, thorax: int) -> None:
        x = b["xfrc_applied"]
        x[sel, :, 0] = self.force[..., 0]
        x[sel, :, 2] = self.force[..., 1]
        x[sel, :, 4] = self.force[..., 2]
        x[sel, thorax, 0] += push_n

    def for_controller(self, rows=slice(None)) -> tuple[np.ndarray, np.ndarray]:
        force = self.known if self.box is not None else self.force
        return (np.ascontiguousarray(force[rows, :self.nb]), np.ascontiguousarray(self.xipos[rows, :self.nb]))

    # --- the lean of a body upright in the world, for rows ``ids`` at step ``k`` (time ``t_s``) --------------
    def lean_x(self, ids: np.ndarray, k: int, t_s: float, com_z: np.ndarray) -> np.ndarray:
        if self.pose is None:
            return self.support.lean_x(t_s, com_z)
        return lean_x(self.pose[ids, k, 0], com_z)

    def lean_rate(self, ids: np.ndarray, k: int, t_s: float, com_z: np.ndarray, com_vel_z: np.ndarray) -> np.ndarray:
        if self.pose is None:
            return self.support.lean_rate(t_s, com_z, com_vel_z)
        return lean_rate(self.pose[ids, k, 0], self.omega[ids, k], com_z, com_vel_z)

    def lean_accel(self, ids: np.ndarray, t_s: float, com_z: np.ndarray):
        """The feed-forward of a prescribed motion; a floating box's is not known ahead (0: felt, as any push)."""
        return 0.0 if self.pose is not None else self.support.lean_accel(t_s, com_z)

    def poses(self, times_s: np.ndarray) -> np.ndarray:
        """(n, steps, 3): the support frame's world pose (theta, x, z) at every step, for the trajectories."""
        if self.pose is not None:
            return self.pose
        theta = self.support.tilt(times_s)[0]
        origin = self.support.origin(times_s)[0]
        one = np.stack([np.broadcast_to(theta, times_s.shape), origin[:, 0], origin[:, 1]], axis=1)
        return np.broadcast_to(one, (1, *one.shape))


class _CompiledTick:
    """The control step of a scoring run in the center mode with feet planted, as one compiled call
    (``cmrt.sim.tick.control_tick``): everything that does not change during the run is bound here once."""

    FIELDS = ("geom_xpos", "geom_xmat", "qpos", "qvel", "cdof", "cdof_dot", "cvel", "cinert", "M", "qfrc_bias",
              "qfrc_passive", "subtree_com", "time")

    def __init__(self, b: dict, geo: _Geometry, controller: MomentumBalanceController, drive: _Drive,
                 rec: _Recorder, falls: FallMonitor, act: np.ndarray, nb: int, mass_kg: float, lean_check: bool,
                 delay_steps: int, fb_vel: np.ndarray, warm: np.ndarray):
        """The monitor ``falls`` brings what a fall is and the clock (``limits``, ``dt``, ``control_dt``)."""
        c, limits, dt, control_dt, n = controller, falls.limits, falls.dt, falls.control_dt, falls.code.size
        variants = drive.variant_of is not None
        # Every row of the batch's fields, read-only and C-contiguous: one numba signature (each costs ~40 s
        # to compile); the kernel reads the active rows, so rows that stop (falls) cost no copies. qpos, qvel
        # and time lie in each simulation's state row (strided): they are copied into C-contiguous buffers
        # per call (``strided``: (bound field, buffer)).
        bound = [b[name] for name in self.FIELDS]
        self.strided = [(f, np.empty(f.shape)) for f in bound if not f.flags.c_contiguous]
        buffers = {id(f): buf for f, buf in self.strided}
        self.fields = tuple(read_only(buffers.get(id(f), f)) for f in bound)
        self.ctrl, self.dt, self.control_dt, self.nb, self.mass_kg = b["ctrl"], dt, control_dt, nb, mass_kg
        self.geometry = (geo.points, geo.body_geoms, geo.half, geo.radius, geo.leg_dofs, geo.root_pitch, act,
                         FOOT_POINT_RADIUS_M, CONTACT_HEIGHT_M, limits.com_height_m, limits.airborne_s,
                         limits.roll_rad, limits.capture_margin_m)
        self.controller = (c.chain, c.m_rows, c.m_cols, c.point_bodies, c.actuated, c.bounds, c.w2, c.params)
        self.drive = (*(read_only(r if variants else r[None]) for r in (drive.q_ref, drive.qd_ref, drive.qdd_ref)),
                      drive.variant_of.astype(np.int64) if variants else np.zeros(n, np.int64),
                      drive.disp_m, drive.disp_vel_m_s)
        self.lean = (lean_check, rec["prop_force"], CONTACT_FORCE_N)
        self.state = (falls.airborne_for_s, falls.code, rec["sc"], rec["lo"], rec["hi"], rec["qpos"], rec["com"],
                      rec["jspeed"], rec["cref"], rec["plan_cop"])
        self.delay = (delay_steps, fb_vel)
        self.warm = (warm, np.zeros_like(warm))  # the active sets, and where this step's are written first

    def __call__(self, k: int, ids: np.ndarray, carried_kg: np.ndarray, com_ref_now: np.ndarray,
                 cop_ref_now: np.ndarray, ctrl_all: np.ndarray, load: tuple | None = None, held: tuple | None = None):
        """Control step ``k`` of rows ``ids``: (point_x, how many fell, the mask of those
        that fell, momentum), or None when the Python path must do it (a fallen row, or a singular plan it
        finds row by row)."""
        for bound, buffer in self.strided:
            np.copyto(buffer, bound)
        n = ids.size
        point_x, momentum, new = np.empty((n, self.geometry[0].size)), np.empty((n, 2)), np.empty(n, bool)
        try:
            fell = control_tick(k, ids, (self.dt, self.control_dt, self.nb, self.mass_kg), self.fields,
                                self.geometry, self.controller, self.drive, self.lean, self.state,
                                (carried_kg, com_ref_now, cop_ref_now, ctrl_all), self.delay, self.warm,
                                _no_load(n) if load is None else tuple(load),
                                _no_held(n) if held is None else tuple(held), (point_x, momentum, new))
        except np.linalg.LinAlgError:
            return None
        if fell < 0:
            return None
        np.copyto(self.ctrl, ctrl_all)  # rows that stopped are not stepped again: their torques do not matter
        return point_x, fell, new, momentum


def simulate_batch(
    task: Task,
    curves: list[Cmrt | None],
    config: ControllerConfig = ControllerConfig(),
    record: bool = False,
    threads: int | None = None,
    limits: BalanceLimits = BalanceLimits(),
    perturbations: Sequence[Perturbation] | None = None,
) -> list[Trajectory]:
    """Simulate one clip (plus standing tail) of ``task`` per CMRT (None: zero CMRT), in lockstep.

    ``record`` fills every array at every step and plays falls out in protective mode;
    scores do not depend on it. ``threads``: how many cores to use (default: all cores,
    or $CMRT_THREADS). ``perturbations``: one per CMRT (an ensemble member: an extra push,
    the prop's mass scaled, the motion's timing scaled; default: the nominal clip).

    With t threads the clips are split into t contiguous groups, each stepped in lockstep by its own
    Python thread on a one-thread ``Batch``: MuJoCo and the compiled controller release the GIL, so
    one group's control step (Python and kernel) runs while the other groups' physics runs. One batch
    on t MuJoCo threads would leave the cores idle through every control step (docs/performance.md).
    A clip's result does not depend on its group (each row is simulated independently; tested)."""
    if getattr(task, "body", "planar") != "planar":  # a 3D task or sequence (cmrt.sim.clip3d plays it)
        raise CmrtError(f"task {task.name!r} is done with the {task.body} body: the planar simulator does not play "
                        "it (cmrt.simulate and cmrt.evaluate take either body; `cmrt render` draws a 3D clip; "
                        "docs/body3d.md)")
    if any(getattr(curve, "axes", 1) != 1 for curve in curves):  # a superposed CMRT (planar) has no axes
        raise CmrtError(f"task {task.name!r}: a CMRT in two axes is for the 3D body (the planar body has one "
                        "horizontal axis)")
    n = len(curves)
    members = list(perturbations) if perturbations is not None else [NOMINAL] * n
    if len(members) != n:
        raise ValueError("one perturbation per CMRT")
    note_first_compile()  # the first clip after an install compiles the controller: say so, once
    groups = min(n, threads or thread_count(n))
    if groups <= 1:
        return _simulate_group(task, curves, config, record, limits, members)
    settled_state(task, config)  # cached once, before the threads share it
    bounds = np.linspace(0, n, groups + 1).round().astype(int)
    parts = [(curves[a:b], members[a:b]) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    with ThreadPoolExecutor(max_workers=groups) as pool:
        done = list(pool.map(lambda part: _simulate_group(task, part[0], config, record, limits, part[1]), parts))
    return [tr for part in done for tr in part]


def _simulate_group(task: Task, curves: list[Cmrt | None], config: ControllerConfig, record: bool,
                    limits: BalanceLimits, members: list[Perturbation]) -> list[Trajectory]:
    """``simulate_batch`` for one group of clips on a one-thread ``Batch``, in the calling thread.

    Three units hand over explicit state: :func:`_set_up` builds the batch and everything bound to it (a
    :class:`_Group`); the compiled scoring loop (:func:`_compiled_loop`) and then the Python loop
    (:func:`_python_loop`) step it, sharing where they are in a :class:`_LoopState`; :func:`_finish` judges
    and returns the trajectories. What drives each row is :class:`_Drive`, the torques :func:`_torques`, the
    balance monitor :class:`FallMonitor`."""
    g = _set_up(task, curves, config, record, limits, members)
    s = _LoopState(ids=np.arange(g.n), next_end=g.run_steps, last=np.full(g.n, g.n_steps))
    if g.compiled is not None:  # a scoring run: compiled control steps, then (a fall, a singular plan) Python
        _compiled_loop(g, s)
    _python_loop(g, s)
    return _finish(g, s)


@dataclass
class _Group:
    """One group's batch and everything bound to it for the run: set up once by :func:`_set_up`, then only
    its arrays' contents change."""

    task: Task
    config: ControllerConfig
    record: bool
    ch: object
    m: mujoco.MjModel
    n: int
    dt: float
    run_steps: int
    post_fall: int
    n_steps: int
    times: np.ndarray
    drive: _Drive
    geo: _Geometry
    controller: MomentumBalanceController
    yu: YuReference | None
    kin: PlanarKinematics
    nq: int
    nb: int
    act: np.ndarray
    batch: mujoco.batch.Batch
    prop: object
    b: dict
    settled_z: np.ndarray
    rec: _Recorder
    limp: ProtectiveMode
    stepper: StepSupervisor | GaitTracker | None
    falls: FallMonitor
    goal: np.ndarray  # the prop's goal: 1/0 (NaN: a pose change), judged at the end or at the fall
    extras: dict
    ctrl_all: np.ndarray
    com_ref_now: np.ndarray  # the references, held between control steps
    cop_ref_now: np.ndarray
    control_dt: float
    sample_every: int
    has_contact_force: bool
    delay_steps: int  # the balance feedback's delay (ControllerConfig.feedback_delay_s), whole control steps
    fb_vel: np.ndarray  # the CoM velocity at every control step so far (its position is in the records)
    felt: np.ndarray | None  # a reactive stepper's inputs at every control step so far (com x, com z, L_x, H_y): it
    # decides from those of ``delay_steps`` ago, as the balance feedback does (None: no reactive stepping)
    warm: np.ndarray  # each simulation's QP active set at its last control step: the next one starts from it
    compiled: _CompiledTick | None
    push_steps: set  # a set: cheaper per step than an array
    field: _SupportField | None = None  # a tilted or moving support's field (None: a still level floor)
    com_ref_shown: np.ndarray | None = None  # the reference CoM as traces show it (``_control_and_monitor``)

    @property
    def diverged_code(self) -> int:
        return 1 + REASONS.index(FallReason.DIVERGED)


@dataclass
class _LoopState:
    """Where the stepping is, handed from the compiled loop to the Python loop: the step, the rows still
    running (``ids``; ``sel`` their batch rows, ``step_ids`` the ids given to ``Batch.step``, None: all), the
    next step at which a row stops, the step whose ``prop.step`` the compiled loop made before handing over,
    the stepping supervisor's last command, and the step each row stopped at."""

    ids: np.ndarray
    next_end: int
    last: np.ndarray
    k: int = 0
    sel: object = field(default_factory=lambda: slice(None))
    step_ids: np.ndarray | None = None
    prop_stepped: int = -1
    step: StepCommand | None = None


def _set_up(task: Task, curves: list[Cmrt | None], config: ControllerConfig, record: bool,
            limits: BalanceLimits, members: list[Perturbation]) -> _Group:
    """The batch of a group's clips in the settled state, its drive, controller, monitor and records."""
    ch = character()
    m = task.model()
    n = len(curves)
    dt = m.opt.timestep
    clip_steps = int(round(task.clip_s / dt))
    run_steps = clip_steps + int(round(task.tail_s / dt))
    post_fall = int(round(POST_FALL_S / dt))
    n_steps = run_steps + (post_fall if record else 0)
    times = np.arange(n_steps) * dt
    drive = _drive(task, [c or Cmrt.zero(task.clip_s) for c in curves], members, times)
    geo = _Geometry()
    controller = MomentumBalanceController(ch, surface_config(config, task))
    yu = YuReference(ch, config.k_l, config.d_l) if task.reference_mode == "yu" else None
    nq, nb = ch.model.nq, ch.model.nbody  # the humanoid's: a prop's coordinates follow
    act = np.array(ch.actuated_dofs)

    batch = mujoco.batch.Batch(m, nsim=n, nthread=1, persistent=True)
    prop = prop_class(task.prop)(m, task.params)
    names = set(CONTROL_FIELDS) | set(STATE_FIELDS) | {"ctrl", "xfrc_applied", "sensordata", "geom_xmat", "time",
                                                       "xipos"}
    support = Support.from_params(task.params)
    if support.floating:  # the box's load: the contact force on the root's coordinates, about the root
        names |= {"qfrc_constraint", "xpos"}
    b = {k: batch.bind(k) for k in names | prop.fields()}
    for k, v in settled_state(task, config).items():
        b[k][:] = v
    b["time"][:] = 0.0
    prop.start(batch, b, n, task.end_qpos(), drive.mass_scale)
    batch.forward(stage=mujoco.mjtStage.mjSTAGE_VEL)
    settled_z = b["geom_xpos"][0, geo.points, 2].copy()

    rec = _Recorder(n, n_steps, m.nq, m.nv, m.nu)
    stepper = _stepper(task, n, config, drive, dt)
    control_dt = config.control_every * dt
    falls = FallMonitor(n, act.size, nq, run_steps, limits, dt, control_dt)
    has_contact_force = prop.contact_force(b, slice(None)) is not None
    delay_steps = config.control_every * int(round(config.feedback_delay_s / control_dt))
    fb_vel = np.full((n, n_steps), np.nan)
    warm = np.zeros((n, controller.n_rows), bool)
    compiled = (_CompiledTick(b, geo, controller, drive, rec, falls, act, nb, ch.mass_kg,
                              has_contact_force and prop.holds_body_up, delay_steps, fb_vel, warm)
                if COMPILED_TICK and yu is None and stepper is None and not record and support.still_and_level
                else None)
    return _Group(
        task=task, config=config, record=record, ch=ch, m=m, n=n, dt=dt, run_steps=run_steps, post_fall=post_fall,
        n_steps=n_steps, times=times, drive=drive, geo=geo, controller=controller, yu=yu,
        kin=PlanarKinematics(ch.model), nq=nq, nb=nb, act=act, batch=batch, prop=prop, b=b, settled_z=settled_z,
        rec=rec, limp=ProtectiveMode(batch, controller.limits), stepper=stepper, falls=falls, goal=np.full(n, np.nan),
        extras={}, ctrl_all=np.zeros((n, m.nu)), com_ref_now=np.full(n, np.nan), cop_ref_now=np.full(n, np.nan),
        control_dt=control_dt, sample_every=max(1, int(round(task.cop_sample_step_s / dt))),
        has_contact_force=has_contact_force, delay_steps=delay_steps, fb_vel=fb_vel, warm=warm, compiled=compiled,
        felt=None if stepper is None else np.full((n, n_steps, 4), np.nan),
        push_steps=set(np.flatnonzero(drive.push_changes).tolist()),
        field=None if support.still_and_level else _SupportField(support, m, nb, n, n_steps, delay_steps),
        com_ref_shown=np.full(n, np.nan),
    )


def _balancing_held(held: tuple | None, targets: Targets, mass_kg: np.ndarray) -> Targets:
    """The CoM target moved so that the body and the share of a held mass the controller balances (``held``:
    ``Prop.held_mass``) stand over it together: c_b = c_r - w m (x_held - c_r) / M_body (the compiled tick's
    operations, bit for bit)."""
    if held is None or not held[3].any():
        return targets
    m, xz, _, share = held
    c = targets.com_x_m
    moved = np.where(share > 0.0, c - share * m * (xz[:, 0] - c) / mass_kg, c)
    return Targets(moved, targets.com_vel_x_m_s, targets.cop_x_m)


def _with_held(g: _Group, ids: np.ndarray, com: np.ndarray, vel_x: np.ndarray,
               held: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The CoM (x, y, z rows) and its x velocity of the character with what its hands hold and its bodies do not
    carry yet (``Prop.held_mass``: a gripped ball before its mass is handed over; ``held`` if the caller has it):
    what balances and falls."""
    held = g.prop.held_mass(g.b, ids) if held is None else held
    if held is None or not held[0].any():
        return com, vel_x
    m, xz, vx = held[:3]
    own = g.ch.mass_kg + g.prop.carried_kg[ids]
    total = own + m
    holding = m > 0.0  # the others' CoM untouched (as the compiled tick's: bit for bit)
    com = com.copy()
    com[:, 0] = np.where(holding, (own * com[:, 0] + m * xz[:, 0]) / total, com[:, 0])
    com[:, 2] = np.where(holding, (own * com[:, 2] + m * xz[:, 1]) / total, com[:, 2])
    return com, np.where(holding, (own * vel_x + m * vx) / total, vel_x)


def _fell_now(g: _Group, s: _LoopState, k: int, new: np.ndarray, qpos: np.ndarray, momentum: np.ndarray) -> int:
    """Rows ``new`` (of ``s.ids``) fell at step ``k``; returns the next step at which a row stops."""
    b, falls, prop, ch = g.b, g.falls, g.prop, g.ch
    sims = s.ids[new]
    com, vel_x = _with_held(g, sims, b["subtree_com"][sims, 1], momentum[new, 0] / (ch.mass_kg + prop.carried_kg[sims]))
    falls.com_vel_x[sims] = vel_x
    with np.errstate(all="ignore"):  # a blow-up's NaNs
        falls.capture_x[sims] = capture_point_x(com[:, 0], com[:, 2], falls.com_vel_x[sims])
    # scoring: stop after this step; recording: play the topple out (not a blow-up: nothing to show)
    falls.fell(sims, k, qpos[new], g.act,
               np.hypot(momentum[new, 0], momentum[new, 1]) / (ch.mass_kg + prop.carried_kg[sims]),
               np.where(g.record & (falls.code[sims] != g.diverged_code), np.maximum(g.run_steps, k + g.post_fall),
                        k + 1))
    _judge_prop(prop, b, sims, g.rec["prop_force"][sims, :k], g.times[:k], g.drive.windows_s, g.goal, g.extras)
    if g.record:
        played = falls.code[sims] != g.diverged_code
        g.limp.fall(sims[played], qpos[new][played])
    return falls.end[s.ids].min()


def _still_running(g: _Group, s: _LoopState, k: int) -> np.ndarray:
    """At the end of the tail, a fall (scoring: after its step) or a played-out topple: the rows that go on."""
    done = g.falls.end[s.ids] <= k
    s.last[s.ids[done]] = k
    return s.ids[~done]


def _compiled_loop(g: _Group, s: _LoopState) -> None:
    """The scoring loop with compiled control steps (cmrt.sim.tick), ground forces summed at the end; it
    hands over to the Python loop at a fallen row or a singular plan (``s.prop_stepped``: that step's
    ``prop.step`` is made)."""
    b, rec, prop, n_steps = g.b, g.rec, g.prop, g.n_steps
    n_points = g.geo.points.size
    touch = np.full((g.n, n_steps, n_points), np.nan)  # normal force at heel_r, toe_r, heel_l, toe_l, every step
    sample_x = np.full((g.n, n_steps, n_points), np.nan)  # heel/toe x at the CoP sample steps
    sensors = b["sensordata"][:, :n_points]
    every, every_step, thorax = g.config.control_every, prop.every_step, g.ch.thorax_body
    step_rows, rows32 = direct_step(g.batch, mujoco.mjtStage.mjSTAGE_VEL), None  # rows32: stepped rows (None: all)
    k = s.k
    while k < n_steps:
        if k >= s.next_end:
            s.ids = _still_running(g, s, k)
            if s.ids.size == 0:
                break
            s.sel = s.step_ids = s.ids
            rows32 = s.ids.astype(np.int32)  # sorted and unique: a subset of arange(n)
            s.next_end = g.falls.end[s.ids].min()
        ids, sel = s.ids, s.sel
        control = k % every == 0
        if control or every_step:
            prop.step(g.batch, b, ids, g.times[k])
        if control:
            out = g.compiled(k, ids, prop.carried_kg, g.com_ref_now, g.cop_ref_now, g.ctrl_all, prop.hand_load(b, ids),
                             prop.held_mass(b, ids))
            if out is None:  # a fallen row or a singular plan: the Python loop goes on from here
                s.prop_stepped = k
                break
            point_x, fell, new, momentum = out
            sample_x[ids, k] = point_x  # the executed CoP of every control step (the plan's) and CoP sample step
            if k % g.sample_every == 0:
                rec["pref"][ids, k] = g.cop_ref_now[ids]
            if fell:
                s.next_end = _fell_now(g, s, k, new, b["qpos"][sel], momentum)
        elif k % g.sample_every == 0:
            sample_support(k, ids, b["geom_xpos"], b["qpos"], b["subtree_com"], g.geo.points, g.cop_ref_now, rec["sc"],
                           rec["lo"], rec["hi"], rec["qpos"], rec["com"], rec["pref"], sample_x)
        if k in g.push_steps:
            b["xfrc_applied"][sel, thorax, 0] = g.drive.push_n[sel, k]
        step_rows(rows32)
        if g.has_contact_force:
            rec["prop_force"][sel, k] = prop.contact_force(b, sel)
        touch[:, k] = sensors  # rows that stopped repeat their last reading: cut off at ``last``
        k += 1
    s.k = k
    _ground_records(rec, touch[:, :k], sample_x[:, :k], g.sample_every, every)


@dataclass
class _Reading:
    """What one step of the Python loop read of its rows' state (fields a step does not need stay None)."""

    geom_xpos: np.ndarray
    qpos: np.ndarray
    point_x: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    center: np.ndarray | None = None
    com: np.ndarray | None = None
    contact: np.ndarray | None = None
    roll: np.ndarray | None = None
    jspeed: np.ndarray | None = None
    lowest: np.ndarray | None = None
    grounded: np.ndarray | None = None
    c_lo: np.ndarray | None = None
    c_hi: np.ndarray | None = None
    momentum: np.ndarray | None = None
    vel_x: np.ndarray | None = None


def _python_loop(g: _Group, s: _LoopState) -> None:
    """The Python path, from where the compiled loop stopped (step 0 if it did not run; nothing left to do if
    no row is left): traces, the yu reference, stepping, and the steps the compiled tick hands back."""
    first = s.k
    for k in range(first, g.n_steps if s.ids.size else first):
        if k >= s.next_end:  # the end of the tail, a fall (scoring: after its step), or the topple played out
            active = _still_running(g, s, k)
            if active.size == 0:
                break
            s.sel = s.ids = s.step_ids = active
            s.next_end = g.falls.end[s.ids].min()
        _python_step(g, s, k)


def _python_step(g: _Group, s: _LoopState, k: int) -> None:
    """One step of the Python loop. Work happens on control steps (balance checks too), CoP sample steps, or
    every step when recording a trace; in between, the batch just steps and the ground force is read (the
    cost floor)."""
    b, sel = g.b, s.sel
    control = k % g.config.control_every == 0
    sample = g.record or k % g.sample_every == 0
    if (control or g.prop.every_step) and k != s.prop_stepped:
        g.prop.step(g.batch, b, s.ids, g.times[k])
    if g.field is not None:
        g.field.update(b, sel, g.times[k], s.ids, k, g.falls.code[s.ids] > 0)
    r = _read(g, s, k, control) if control or sample else None
    if control or g.record:
        _read_motion(g, s, k, r, control)
    if control:
        _control_and_monitor(g, s, k, r)
    if g.record:
        g.rec["ctrl"][sel, k] = g.ctrl_all[sel]
        g.rec["cref"][sel, k] = g.com_ref_now[sel] if g.field is None else g.com_ref_shown[sel]
        g.rec["qvel"][sel, k] = b["qvel"][sel]
    if g.field is not None:
        g.field.apply(b, sel, g.drive.push_n[sel, k], g.ch.thorax_body)
    elif k in g.push_steps:
        b["xfrc_applied"][sel, g.ch.thorax_body, 0] = g.drive.push_n[sel, k]

    g.batch.step(ids=s.step_ids, stage=mujoco.mjtStage.mjSTAGE_VEL)

    if g.has_contact_force:
        g.rec["prop_force"][sel, k] = g.prop.contact_force(b, sel)
    _record_ground(g, s, k, None if r is None else r.point_x, sample, control)


def _read(g: _Group, s: _LoopState, k: int, control: bool) -> _Reading:
    """The support and CoM of rows ``s.ids`` at the state step ``k`` starts from, recorded; on a control step
    also the monitor's inputs (one pass) and the stepping supervisor's command."""
    b, sel, ids, rec = g.b, s.sel, s.ids, g.rec
    geom_xpos = b["geom_xpos"][sel]
    qpos = b["qpos"][sel]
    if control:  # heel/toe x at the state the step starts from, and the monitor's inputs: one pass
        point_x, lo, hi, contact, roll, jspeed, lowest, grounded, c_lo, c_hi = g.geo.at_control(
            geom_xpos, b["geom_xmat"][sel], qpos, b["qvel"][sel], g.act)
        r = _Reading(geom_xpos, qpos, point_x, lo, hi, contact=contact, roll=roll, jspeed=jspeed, lowest=lowest,
                     grounded=grounded, c_lo=c_lo, c_hi=c_hi)
    else:
        point_x = geom_xpos[:, g.geo.points, 0]
        r = _Reading(geom_xpos, qpos, point_x, point_x.min(axis=1), point_x.max(axis=1))
    if g.stepper is not None:  # the support of the moment: the stance foot while the other swings
        if control:
            s.step = _step_command(g.stepper, g.kin, b, sel, ids, g.times[k], g.ch.mass_kg + g.prop.carried_kg[ids],
                                   r.contact, r.point_x, (g.drive.disp_m[sel, k], g.drive.disp_vel_m_s[sel, k]),
                                   (g.felt, k, g.delay_steps))
        r.lo, r.hi = g.stepper.support(ids, r.point_x, r.lo, r.hi)
    r.center = 0.5 * (r.lo + r.hi)
    rec["sc"][sel, k], rec["lo"][sel, k], rec["hi"][sel, k] = r.center, r.lo, r.hi
    if g.stepper is not None:  # a swing foot still or already loaded on the floor (lifting off a loaded rear foot;
        # a touchdown is seen at the next control step) and the measured CoP counts it: the support it is measured
        # against includes its loaded points
        touching = g.stepper.swinging(ids).repeat(2, axis=1) & (b["sensordata"][sel, :4] >= PLANTED_FORCE_N)
        if touching.any():
            rec["lo"][sel, k] = np.fmin(r.lo, np.where(touching, r.point_x, np.inf).min(axis=1))
            rec["hi"][sel, k] = np.fmax(r.hi, np.where(touching, r.point_x, -np.inf).max(axis=1))
    rec["qpos"][sel, k] = qpos
    r.com = b["subtree_com"][sel, 1]
    rec["com"][sel, k, 0], rec["com"][sel, k, 1] = r.com[:, 0], r.com[:, 2]  # x, z without a fancy-indexed copy
    return r


def _read_motion(g: _Group, s: _LoopState, k: int, r: _Reading, control: bool) -> None:
    """The linear momentum and CoM velocity of a control or recorded step, and the trace-only quantities."""
    b, sel, rec = g.b, s.sel, g.rec
    if not control:
        r.contact = _in_contact(r.geom_xpos, g.geo.points)
        r.roll = g.geo.foot_roll(r.qpos)
    r.momentum = g.kin.linear_momentum(b["cinert"][sel, :g.nb], b["cvel"][sel, :g.nb])  # (k, 2): L_x, L_z
    r.vel_x = r.momentum[:, 0] / (g.ch.mass_kg + g.prop.carried_kg[s.ids])
    if g.record:  # trace-only quantities
        rec["com_vel"][sel, k] = r.vel_x
        rec["xi"][sel, k] = capture_point_x(r.com[:, 0], r.com[:, 2], r.vel_x)
        rec["lift"][sel, k] = r.geom_xpos[:, g.geo.points, 2] - g.settled_z
        rec["contact"][sel, k] = r.contact
        rec["roll"][sel, k] = r.roll
        rec["body_z"][sel, k] = r.lowest if control else g.geo.lowest_body_z(r.geom_xpos, b["geom_xmat"][sel])


def _leaning(g: _Group, k: int, targets: Targets, com_z: np.ndarray, com_vel_z: np.ndarray,
             s_ids: np.ndarray) -> Targets:
    """The targets on a tilting support: the CoM over the support centre along gravity, moving with it
    (``Support.lean_x``; Yu's mode has it from its reference pose, upright in the world). The delayed feedback
    compares the CoM of ``tau`` ago with the lean of then (the balance feedback's delay, ``_delayed``, shifts the
    CoM, so the lean is taken at t - tau here); the lean's
    acceleration at t is fed forward through the CoM stiffness, k_l m (c_r + a / k_l - c) asking m a more of the
    momentum rate: the platform's motion is a known pattern, as a reference motion is. Without the feed-forward
    the PD feedback lags a +-20 degree, 0.5 Hz plane's +-0.35 m lean by ~27 degrees; with the lean of t instead of
    t - tau the delayed feedback sees 0.1 s of the lean's travel (up to 0.1 m) as an error (measured: both fall)."""
    field, t_now, ids = g.field, g.times[k], None if g.field.pose is None else s_ids
    k_felt = max(k - g.delay_steps, 0)
    t_felt = max(t_now - g.delay_steps * g.dt, 0.0)
    lean = field.lean_x(ids, k_felt, t_felt, com_z) + field.lean_accel(ids, t_now, com_z) / g.config.k_l
    rate = field.lean_rate(ids, k_felt, t_felt, com_z, com_vel_z)
    if g.yu is not None and field.pose is None:  # Yu's target already leans with its (tilted) reference pose, at t:
        # moved to t - tau (a floating box's tilt is not in the reference pose: it is not known ahead)
        lean = lean - field.lean_x(ids, k, t_now, com_z)
        rate = rate - field.lean_rate(ids, k, t_now, com_z, com_vel_z)
    return Targets(targets.com_x_m + lean, targets.com_vel_x_m_s + rate, targets.cop_x_m)


def _control_and_monitor(g: _Group, s: _LoopState, k: int, r: _Reading) -> None:
    """A control step of rows ``s.ids``: the references, the torques, then the balance monitor."""
    b, sel, ids, rec, stepper = g.b, s.sel, s.ids, g.rec, g.stepper
    rec["jspeed"][sel, k] = r.jspeed
    mass = g.ch.mass_kg + g.prop.carried_kg  # what the controller knows it carries
    targets = _targets(g.yu, b, sel, ids, g.drive, k, r.center, r.lo, r.hi, r.com, r.vel_x, g.nb,
                       None if g.field is None else g.field.lean_x(ids, k, g.times[k], r.com[:, 2]))
    held = g.prop.held_mass(b, ids)  # read once: nothing moves before the monitor reads it too
    targets = _balancing_held(held, targets, mass[ids])
    shown = targets.com_x_m  # the reference CoM as recorded: where the CoM is asked to be now
    if g.field is not None:  # the CoM over the support centre along gravity, moving with it
        com_vel_z = r.momentum[:, 1] / (g.ch.mass_kg + g.prop.carried_kg[ids])
        lean_vel = g.field.lean_rate(ids, k, g.times[k], r.com[:, 2], com_vel_z)
        if g.yu is None or g.field.pose is not None:  # (without the delay's shift and the feed-forward the
            # controller is given; Yu's reference pose leans with a prescribed tilt, not with a box's)
            shown = shown + g.field.lean_x(ids, k, g.times[k], r.com[:, 2])
        targets = _leaning(g, k, targets, r.com[:, 2], com_vel_z, ids)
    g.com_ref_now[ids], g.cop_ref_now[ids] = targets.com_x_m, targets.cop_x_m
    g.com_ref_shown[ids] = shown
    rec["cref"][sel, k] = shown
    g.fb_vel[ids, k] = r.vel_x
    felt = _delayed(targets, g.delay_steps, k, ids, r.com[:, 0], r.vel_x, rec["com"], g.fb_vel)
    ctrl, bad, plan_cop = _torques(g.controller, b, sel, ids, g.falls.code[ids] > 0, g.drive, k, felt, r.contact,
                                   mass, g.m.nu, s.step, g.warm, g.prop,
                                   None if g.field is None else g.field.for_controller())
    # the plan against the CoP measured in the physics step these torques act in (plan vs execution)
    swinging = np.zeros(ids.size, bool) if stepper is None else stepper.swinging(ids).any(axis=1)
    rec["plan_cop"][sel, k] = np.where(swinging, np.nan, plan_cop)
    g.ctrl_all[ids] = ctrl
    b["ctrl"][sel] = ctrl

    # the balance monitor
    c_lo, c_hi, roll = r.c_lo, r.c_hi, r.roll
    if stepper is not None:  # a swing foot is not a rolled foot; where it lands is support
        c_lo, c_hi = stepper.landing_span(ids, c_lo, c_hi)
        if isinstance(stepper, StepSupervisor):  # a reactive stepper: what one step can still catch is not yet a fall
            c_lo, c_hi = stepper.step_reach_span(ids, c_lo, c_hi)
        roll = np.where(stepper.swinging(ids), 0.0, roll)
    if g.has_contact_force and k > 0 and g.prop.holds_body_up:  # leaning on a prop: the pendulum's capture point
        leaning = rec["prop_force"][ids, k - 1] > CONTACT_FORCE_N  # does not apply
        c_lo, c_hi = np.where(leaning, -np.inf, c_lo), np.where(leaning, np.inf, c_hi)
    com, vel_x = _with_held(g, ids, r.com, r.vel_x, held)
    if g.field is not None:  # the CoM where the field projects it onto the support (its capture point from there)
        com = com.copy()
        com[:, 0] -= g.field.lean_x(ids, k, g.times[k], com[:, 2])
    vel_x = vel_x if g.field is None else vel_x - lean_vel
    new = g.falls.check(ids, k, ok=~bad, grounded=r.grounded, support_lo_x=c_lo, support_hi_x=c_hi,
                        lowest_body_z=r.lowest, qpos=r.qpos, com=com, com_vel_x=vel_x, roll=roll,
                        time_s=b["time"][sel])
    if new.any():
        s.next_end = _fell_now(g, s, k, new, r.qpos, r.momentum)


def _record_ground(g: _Group, s: _LoopState, k: int, point_x: np.ndarray | None, sample: bool,
                   control: bool = False) -> None:
    """The ground force after step ``k`` (every step: peak force, time airborne), the measured CoP at the
    control steps (against the plan) and the sample steps, and there the reference CoP and each foot's force."""
    sel, rec = s.sel, g.rec
    rec_fz = rec["fz"]
    touch = g.b["sensordata"][sel, :g.geo.points.size]  # normal force at heel_r, toe_r, heel_l, toe_l
    if not sample and not control:  # the steps in between: the ground force only (peak force, time airborne)
        if s.step_ids is None:  # all active: write straight into the buffer's column
            np.add.reduce(touch, axis=1, out=rec_fz[:, k])
        else:
            rec_fz[sel, k] = touch.sum(axis=1)
        return
    fz = touch.sum(axis=1)
    rec_fz[sel, k] = fz
    with np.errstate(all="ignore"):
        rec["cop"][sel, k] = np.where(fz > 1e-9, (touch * point_x).sum(axis=1) / fz, np.nan)
    if not sample:
        return
    rec["pref"][sel, k] = g.cop_ref_now[sel]
    rec["ffz"][sel, k, 0] = touch[:, :2].sum(axis=1)
    rec["ffz"][sel, k, 1] = touch[:, 2:].sum(axis=1)
    rec["pfz"][sel, k] = touch


def _finish(g: _Group, s: _LoopState) -> list[Trajectory]:
    """The trajectories: each row judged at its fall or, standing, as the run left it."""
    b, falls, nb = g.b, g.falls, g.nb
    momentum = g.kin.linear_momentum(b["cinert"][:, :nb], b["cvel"][:, :nb])
    fallen = falls.code > 0  # judged at the fall, whatever a recorded topple did afterwards
    final_qpos = np.where(fallen[:, None], falls.qpos, b["qpos"][:, :g.nq])
    speed = np.hypot(momentum[:, 0], momentum[:, 1]) / (g.ch.mass_kg + g.prop.carried_kg)
    if g.field is not None:  # relative to the world-upright lean (at rest by now: the support stops before the tail)
        vel = momentum / (g.ch.mass_kg + g.prop.carried_kg)[:, None]
        for i in range(g.n):
            k_end = min(s.last[i], g.n_steps) - 1
            vel[i, 0] -= float(np.squeeze(g.field.lean_rate(np.array([i]), k_end, float(b["time"][i]),
                                                            b["subtree_com"][i, 1, 2], vel[i, 1])))
        speed = np.hypot(vel[:, 0], vel[:, 1])
    final_speed = np.where(fallen, falls.speed_m_s, speed)
    standing = np.flatnonzero(~fallen)  # the others were judged when they fell
    _judge_prop(g.prop, b, standing, g.rec["prop_force"][standing, :g.run_steps], g.times[:g.run_steps],
                g.drive.windows_s, g.goal, g.extras)
    return _trajectories(g.task, g.rec, g.times, s.last, falls, g.drive.disp_m, g.extras, g.goal, final_qpos,
                         final_speed, g.stepper, None if g.field is None else g.field.poses(g.times),
                         g.drive.push_n)


def _stepper(task: Task, n: int, controller: ControllerConfig, drive: _Drive, dt: float
             ) -> StepSupervisor | GaitTracker | None:
    """The stepping supervisor a task asks for (``stepping`` parameter, or a footstep plan: the momentum
    supervisor then watches it), the tracker of its keyed gait (its pushes' adjustment against the reference
    motion's CoM, in Yu's mode), or None: feet stay planted."""
    ch = character()
    heel, toe = (ch.model.geom_pos[g, 0] for g in ch.foot_point_geoms[:2])
    if task.gait is not None:
        heel_z = ch.model.geom_pos[ch.foot_point_geoms[0], 2]
        g, ankle_z0_m = task.gait, stand_frame(ch, task.start_qpos()).ankle_z_m
        swings = KeyedSwings(foot=np.array([g.foot(j) for j in range(g.n_steps)]),
                             lift_off_s=np.array([g.lift_off_s(j) for j in range(g.n_steps)]), swing_s=g.swing_s,
                             feet_paths=functools.partial(feet_paths, g, ankle_z0_m=ankle_z0_m),
                             foot_to_com_x_m=None if drive.motion_com is None else drive.motion_com[0].foot_to_com_x_m,
                             foot_to_com_vel_x_m_s=None if drive.motion_com is None
                             else drive.motion_com[0].foot_to_com_vel_x_m_s, step_s=dt,
                             delay_s=controller.feedback_delay_s)
        return GaitTracker(n, swings, heel_to_ankle_m=(heel, heel_z), foot_length_m=toe - heel)
    config = StepConfig.from_task(task.params)
    if config is None and not task.steps:
        return None
    if config is None:
        config = StepConfig.from_task({**task.params, "stepping": float(MOMENTUM)})
    plan = None
    if task.steps:
        steps = task.plan
        plan = StepPlan(foot=np.array([s.foot for s in steps]), x_m=np.array([s.x_m for s in steps]),
                        duration_s=np.array([s.duration_s for s in steps]),
                        start_s=np.array([np.nan if s.start_s is None else s.start_s for s in steps]),
                        first_step_s=FIRST_STEP_S, double_support_s=DOUBLE_SUPPORT_S, com_stiffness=controller.k_l)
    return StepSupervisor(n, config, heel_to_center_m=0.5 * (toe - heel), foot_length_m=toe - heel, plan=plan,
                          stance=functools.partial(leg_offsets, task.end_qpos()))


def _step_command(stepper: StepSupervisor | GaitTracker, kin: PlanarKinematics, b: dict, sel, ids: np.ndarray,
                  time_s: float, mass: np.ndarray, contact: np.ndarray, point_x: np.ndarray,
                  cmrt: tuple | None = None, delayed: tuple | None = None) -> StepCommand:
    """Advance the supervisor of simulations ``ids`` by one control step from their bound state; ``cmrt``: their
    CMRT displacement and its rate now (a footstep plan's capture point is displaced by it).

    A person's reaction: a reactive stepper decides - whether to step, where, how far to stretch the step - from
    the CoM and momenta of the balance feedback's delay ago (``delayed``: (history (n, steps, 4), this control
    step, the delay in steps), the history written here; people lift the foot 0.25-0.35 s after a push). Before
    the clip's first ``delay`` steps the character stood still: its first control step stands in for them."""
    nb = kin.model.nbody
    momentum = kin.momentum(b["cinert"][sel, :nb], b["cvel"][sel, :nb])  # (k, 3): H_y, L_x, L_z
    com = b["subtree_com"][sel, 1]
    felt = None
    if delayed is not None and delayed[0] is not None:
        history, k, delay_steps = delayed
        history[ids, k] = np.stack([com[:, 0], com[:, 2], momentum[:, 1], momentum[:, 0]], axis=1)
        then = history[ids, max(k - delay_steps, 0)]
        then = np.where(np.isnan(then), history[ids, 0], then)
        felt = (then[:, 0], then[:, 1], then[:, 2], then[:, 3])
    if felt is None:
        return stepper.update(ids, time_s, com[:, 0], com[:, 2], momentum[:, 1], momentum[:, 0], mass, contact,
                              point_x, cmrt)
    return stepper.update(ids, time_s, com[:, 0], com[:, 2], momentum[:, 1], momentum[:, 0], mass, contact,
                          point_x, cmrt, felt)


def _trajectories(task: Task, rec: _Recorder, times: np.ndarray, last: np.ndarray, falls: FallMonitor, disp: np.ndarray,
                  extras: dict[str, np.ndarray], goal: np.ndarray, final_qpos: np.ndarray,
                  final_speed: np.ndarray, stepper: StepSupervisor | GaitTracker | None = None,
                  poses: np.ndarray | None = None, push_n: np.ndarray | None = None) -> list[Trajectory]:
    """One Trajectory per simulation, cut where it stopped."""
    out = []
    for i in range(last.size):
        r = rec.cut(i, last[i])
        code = falls.code[i]
        reason = REASONS[code - 1] if code else None
        protective = np.zeros(last[i], bool)
        if code:
            protective[falls.step[i] + 1 :] = True
        out.append(Trajectory(
            time_s=times[: last[i]], qpos=r["qpos"], qvel=r["qvel"], com_m=r["com"], com_vel_x_m_s=r["com_vel"],
            capture_point_x_m=r["xi"], cop_x_m=r["cop"], support_center_x_m=r["sc"], support_lo_x_m=r["lo"],
            support_hi_x_m=r["hi"], normal_force_n=r["fz"], foot_normal_force_n=r["ffz"],
            point_normal_force_n=r["pfz"], point_lift_m=r["lift"],
            point_contact=r["contact"],
            foot_roll_rad=r["roll"], prop_force_n=r["prop_force"], max_joint_speed_rad_s=r["jspeed"],
            cmrt_displacement_m=disp[i, : last[i]], prop_extras={k: float(v[i]) for k, v in extras.items()},
            com_ref_x_m=r["cref"], cop_ref_x_m=r["pref"], ctrl_nm=r["ctrl"], plan_cop_x_m=r["plan_cop"],
            lowest_body_z_m=r["body_z"], protective=protective, clip_s=task.clip_s,
            fell=bool(code), fall_time_s=float(times[falls.step[i]]) if code else None, fall_reason=reason,
            diverged=reason is FallReason.DIVERGED, final_qpos=final_qpos[i],
            final_com_speed_m_s=float(final_speed[i]),
            fall_capture_point_x_m=float(falls.capture_x[i]) if code else None,
            fall_com_vel_x_m_s=float(falls.com_vel_x[i]) if code else None,
            task_success=None if np.isnan(goal[i]) else bool(goal[i]),
            step_times_s=() if stepper is None else tuple(t for t in stepper.step_times[i]
                                                          if not code or t <= times[falls.step[i]]),
            footprints=() if stepper is None else tuple(f for f in stepper.footprints[i]
                                                        if not code or f[1] <= times[falls.step[i]]),
            flat_times_s=() if stepper is None else tuple(t for t in stepper.flat.times[i]
                                                          if not code or t <= times[falls.step[i]]),
            footstep_errors_m=() if stepper is None else tuple(e for t, e in stepper.placement_error_m[i]
                                                               if not code or t <= times[falls.step[i]]),
            support_pose=None if poses is None else poses[min(i, poses.shape[0] - 1), : last[i]].copy(),
            push_n=None if push_n is None or not push_n[i].any() else push_n[i, : last[i]].copy(),
        ))
    return out


def simulate(
    task: Task, curve: Cmrt | None = None, config: ControllerConfig = ControllerConfig(), record: bool = True
) -> Trajectory:
    """Simulate one clip of ``task`` with CMRT ``curve`` (None: zero CMRT), recording everything."""
    return simulate_batch(task, [curve], config, record=record)[0]
