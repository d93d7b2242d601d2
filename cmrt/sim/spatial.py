"""A 3D clip: the 3D body standing under ``cmrt.control.spatial``'s momentum controller, pushed or not.

MuJoCo steps the physics at the model's 2 ms; the controller plans every ``control_every`` steps (125 Hz, as the
planar clips) and its torques are held between. A push is a force on the thorax (``push_n``, world frame, N) for
``push_duration_s``. The executed CoP is the touch sensors' (every foot point's normal force at its place), the
planned one the controller's point forces'. The controller plans a force on each point on the floor: its lowest
point within ``CONTACT_HEIGHT_M`` (1 mm) of it, the planar controller's rule. (By the touch sensors - any force at
all - a heel point that went slack for a physics step under a caught ball's load lost its floor in the plan, whose
CoP then ran to the toes and rolled the feet onto them: the first 3D catch broke ``plan`` by 15-25 mm and
``cop_margin``, measured; docs/body3d.md.) The body has fallen by the planar monitor's rules
(``cmrt.sim.balance``): its capture point more than 1 cm outside the support polygon, or its CoM below 0.55 m; the
fall then plays out in the planar protective mode (motors off, the joints passive springs about the pose it fell
in). The fall's direction is where the capture point left the support, the topple's where the CoM went by the end
of the clip. A task's prop (a ball to catch) runs in the clip through ``cmrt.sim.prop3d``.

The verdict is the planar one's for a clip without a motion to perform (the same bounds, ``cmrt.sim.objective``):
``balance`` (no fall), ``settled`` (the CoM still at the end), ``plan`` (planned and executed CoP within 5 mm on
each axis outside the impact windows) and ``cop_margin`` (the executed CoP at least 1 mm inside the support
polygon - the convex hull of the touching points - in every sample judged).
"""

from __future__ import annotations

import copy
import functools
import threading
from collections.abc import Callable
from dataclasses import dataclass, replace

import mujoco
import numpy as np

from cmrt.body.character import (
    FOOT_POINT_RADIUS_M,
    GRAVITY_M_S2,
    character,
    feet_flat_qpos,
    joint_angles_from_pose,
)
from cmrt.body.one_leg import one_leg_poses
from cmrt.control import spatial_kernel
from cmrt.control.compiled import note_first_compile
from cmrt.control.controller import ControllerConfig
from cmrt.control.spatial import SpatialController, SpatialPlan, SpatialTargets, SpatialTargetTable
from cmrt.errors import CmrtError
from cmrt.motion.curve import Cmrt
from cmrt.sim import mjc, spatial_loop
from cmrt.sim.balance import BalanceLimits
from cmrt.sim.monitor import PROTECTIVE_DAMPING_PER_RAD_S, PROTECTIVE_STIFFNESS_PER_RAD
from cmrt.sim.objective import (
    FALL_PENALTY,
    MAX_AIRBORNE_S,
    MAX_GROUND_FORCE_BW,
    MAX_PLAN_COP_ERROR_M,
    MIN_COP_MARGIN_M,
    NOT_PLAUSIBLE_PENALTY,
    SETTLED_COM_SPEED_M_S,
    contact_summary,
)
from cmrt.sim.prop3d import HeldProp, PropClip, balancing_held, force_times_s, with_held
from cmrt.sim.simulate import CONTACT_HEIGHT_M, PLANTED_FORCE_N

BODY = "humanoid3d"
IMPACT_WINDOW_S = 0.1  # after a push starts, plan and execution may part (the planar verdict's impact window)
SETTLE_S = 0.1  # the first contacts settle from the initial pose: not judged


@dataclass(frozen=True)
class ClipInputs:
    """What a 3D clip's physics is given besides its motors' torques: where it starts, the push on the thorax
    (world frame, N; from ``push_start_s`` for ``push_duration_s``), the held prop, its length and control period
    (physics steps per control step) - with ``StandResult.ctrl_nm``, enough to step the same clip again open loop
    (``replay_3d``: the physics floor ``cmrt bench`` measures)."""

    start_qpos: np.ndarray
    push_n: tuple[float, float, float]
    push_start_s: float
    push_duration_s: float
    held: HeldProp | None
    clip_s: float
    control_every: int


@dataclass(frozen=True)
class StandResult:
    """A 3D standing clip, sampled at every control step."""

    time_s: np.ndarray  # (n,)
    qpos: np.ndarray  # (n, nq): the pose at each sample (renders)
    com_m: np.ndarray  # (n, 3)
    cop_xy_m: np.ndarray  # (n, 2) executed: the touch sensors' over the control step before the sample
    plan_cop_xy_m: np.ndarray  # (n, 2) planned for that control step: the controller's point forces'
    fell: bool
    fall_time_s: float | None
    fall_direction_xy: np.ndarray | None  # unit vector: where the capture point left the support (from its centre)
    topple_direction_xy: np.ndarray | None  # unit vector: where the CoM went by the clip's end (protective mode)
    final_com_speed_m_s: float
    max_plan_cop_error_m: float  # |planned - executed| per axis, the larger, outside impact windows
    min_cop_margin_m: float  # the executed CoP's distance inside the support polygon, outside impact windows
    infeasible_steps: int  # control steps with no plan within the stops and motors' limits
    failed_rules: tuple[str, ...]  # of the verdict, in order; empty for a success
    peak_normal_force_bw: float = float("nan")  # these four outside the impact windows, before a fall
    airborne_s: float = 0.0
    max_joint_speed_rad_s: float = float("nan")
    max_foot_slip_m: float = 0.0
    prop_goal: bool | None = None  # a held prop's goal met (a ball caught and held); None: no prop
    prop_force_n: np.ndarray | None = None  # the hands' force on the prop, every physics step (N)
    prop_extras: tuple[tuple[str, float], ...] = ()  # the prop's own figures (``Prop.extras``)
    ctrl_nm: np.ndarray | None = None  # (n, nu) the motors' commands held from each sample on (0 after a fall)
    inputs: ClipInputs | None = None  # the rest of what the physics was given (``replay_3d``)

    @property
    def success(self) -> bool:
        """Stood (or was pushed and recovered), still at the end, the plan what happened, the CoP inside."""
        return not self.failed_rules


def stand_pose_qpos(pose_deg: dict[str, float] | None = None) -> np.ndarray:
    """The 3D body standing feet flat in a pose (degrees by joint name; default: the stand task's, every joint at
    zero)."""
    return _pose_qpos(tuple(sorted((pose_deg or {}).items()))).copy()


@functools.lru_cache(maxsize=64)
def _pose_qpos(pose_deg: tuple[tuple[str, float], ...]) -> np.ndarray:
    """``stand_pose_qpos``, once per pose (its balance solve was a tenth of a clip's Python)."""
    return feet_flat_qpos(joint_angles_from_pose({k: np.radians(v) for k, v in pose_deg}, BODY), body=BODY)


def feet_centre_xy(qpos: np.ndarray) -> np.ndarray:
    """The centre of the 3D body's foot points in pose ``qpos`` (world x, y; m): both feet's support centre."""
    ch = character(BODY)
    d = _scratch()
    d.qpos[:] = qpos
    mujoco.mj_kinematics(ch.model, d)
    return d.geom_xpos[list(ch.foot_point_geoms), :2].mean(axis=0)


_local = threading.local()


def _scratch() -> mujoco.MjData:
    """A data of the body's model for kinematics passes, one per thread (a new MjData costs 0.35 ms: two a leg lift
    were a sixth of its clip's Python)."""
    if not hasattr(_local, "data"):
        _local.data = mujoco.MjData(character(BODY).model)
    return _local.data


@dataclass(frozen=True)
class ClipSamples:
    """What a clip records, written in place by either loop (``spatial_loop.run_clip``, ``_run_python``): at
    each control step (n samples) the CoM, the executed and the planned CoP, the pose, the CoP's margin, the
    planted points' places, the fastest joint and the motors' commands held from it on; at every physics step the
    foot points' touch sensors."""

    com_m: np.ndarray  # (n, 3)
    cop_xy_m: np.ndarray  # (n, 2) executed: the touch sensors' over the control step before the sample
    plan_cop_xy_m: np.ndarray  # (n, 2) planned for that control step (NaN after a fall)
    qpos: np.ndarray  # (n, nq) the clip's model's (a prop's coordinates after the body's)
    margin_m: np.ndarray  # (n,)
    planted_xy_m: np.ndarray  # (n, points, 2): NaN where a point carries less than PLANTED_FORCE_N
    joint_speed_rad_s: np.ndarray  # (n,)
    ctrl_nm: np.ndarray  # (n, nu)
    touch_n: np.ndarray  # (physics steps, points)

    @classmethod
    def empty(cls, steps: int, every: int, m: mujoco.MjModel, n_points: int) -> ClipSamples:
        n = -(-steps // every)  # the control steps: every ``every``-th physics step from the first
        return cls(np.empty((n, 3)), np.empty((n, 2)), np.empty((n, 2)), np.empty((n, m.nq)), np.empty(n),
                   np.empty((n, n_points, 2)), np.empty(n), np.empty((n, m.nu)), np.empty((steps, n_points)))

    def arrays(self) -> tuple[np.ndarray, ...]:
        """In field order: what ``spatial_loop.run_clip`` writes."""
        return (self.com_m, self.cop_xy_m, self.plan_cop_xy_m, self.qpos, self.margin_m, self.planted_xy_m,
                self.joint_speed_rad_s, self.ctrl_nm, self.touch_n)


def stand_3d(clip_s: float = 3.0, push_n: tuple[float, float, float] = (0.0, 0.0, 0.0), push_start_s: float = 1.0,
             push_duration_s: float = 0.1, config: ControllerConfig = ControllerConfig(),
             motion: SpatialTargetTable | None = None, start_qpos: np.ndarray | None = None,
             held: HeldProp | None = None, compiled: bool = True) -> StandResult:
    """Simulate the 3D body standing for ``clip_s`` (from ``start_qpos``, default the standing pose), pushed at the
    thorax by ``push_n``; ``motion``: the controller's targets at each control step (None: hold the start pose);
    ``held``: the task's prop (a ball to catch), its load on the hands known to the plan and its held mass counted
    in what balances and falls. A fall plays out in the planar clips' protective mode. A clip without a prop runs
    whole in compiled code (``cmrt.sim.spatial_loop``; ``compiled=False``: the Python loop a prop needs, the same
    clip bit for bit - for the tests that say so)."""
    ch = character(BODY)
    inputs = ClipInputs(stand_pose_qpos() if start_qpos is None else np.asarray(start_qpos, float),
                        tuple(float(f) for f in push_n), push_start_s, push_duration_s, held, clip_s,
                        config.control_every)
    m, d, prop = _clip_start(inputs)
    ctl = SpatialController(ch, d.qpos[:ch.model.nq].copy(), config, model=m)
    table = motion if motion is not None else SpatialTargetTable()
    steps = int(round(clip_s / m.opt.timestep))
    out = ClipSamples.empty(steps, config.control_every, m, len(ch.foot_point_geoms))
    if prop is None and compiled and mjc.c_functions() is not None:
        note_first_compile(dispatcher=spatial_loop.run_clip)  # the first 3D clip after an install compiles: say so
        fall, infeasible = _run_compiled(m, d, ctl, inputs, table, out)
    else:
        note_first_compile(dispatcher=spatial_kernel.plan_step)
        fall, infeasible = _run_python(m, d, ctl, inputs, table, prop, out)
    result = _finished(m, d, ctl, out, (fall, infeasible), push_start_s, prop)
    return replace(result, ctrl_nm=out.ctrl_nm, inputs=inputs)


def _run_compiled(m: mujoco.MjModel, d: mujoco.MjData, ctl: SpatialController, inputs: ClipInputs,
                  table: SpatialTargetTable, out: ClipSamples) -> tuple[tuple[float, np.ndarray] | None, int]:
    """A clip without a prop, whole in ``spatial_loop.run_clip``: returns (the fall: its time and the capture
    point's way out, or None; the control steps without a plan within the limits)."""
    ch, c = character(BODY), mjc.c_functions()
    ctl.start(d)
    points = np.array(ch.foot_point_geoms, dtype=np.int64)
    fields = (d.cdof, d.cdof_dot, d.cvel, d.cinert, d.qpos, d.qvel, d.M, d.qfrc_bias, d.subtree_com, d.geom_xpos,
              d.xpos, d.xquat)
    data = (d.qpos, d.qvel, d.ctrl, d.xfrc_applied, d.sensordata[:points.size], d.geom_xpos, d.subtree_com,
            d.subtree_linvel, d.xmat, fields)
    dt = m.opt.timestep
    clip = (out.touch_n.shape[0], inputs.control_every, dt, SETTLE_S - 1e-12, np.asarray(inputs.push_n, float),
            inputs.push_start_s, inputs.push_start_s + inputs.push_duration_s, ch.thorax_body, points,
            np.array(ch.actuated_dofs, dtype=np.int64), PLANTED_FORCE_N, FOOT_POINT_RADIUS_M, CONTACT_HEIGHT_M)
    controller = (ctl.compiled_parts(), ctl.mass_kg, ctl.com_ref_m)
    judge = (*_feet(), _LIMITS_VECTOR, _protective_parts(m))
    fall_k, offset, infeasible = spatial_loop.run_clip(
        c.step, c.subtree_vel, (m._address, d._address), data, clip, controller,
        ctl.table_arrays(table, out.com_m.shape[0]), judge, out.arrays())
    return (None if fall_k < 0 else (fall_k * dt, offset)), int(infeasible)


def _run_python(m: mujoco.MjModel, d: mujoco.MjData, ctl: SpatialController, inputs: ClipInputs,
                   table: SpatialTargetTable, prop: PropClip | None, out: ClipSamples
                   ) -> tuple[tuple[float, np.ndarray] | None, int]:
    """``spatial_loop.run_clip``'s loop in Python, with the prop's logic at every physics step; the same returns."""
    ch = character(BODY)
    points = np.array(ch.foot_point_geoms)
    n_pts, acts, every, dt = len(points), np.array(ch.actuated_dofs), inputs.control_every, m.opt.timestep
    push, push_end = np.asarray(inputs.push_n, float), inputs.push_start_s + inputs.push_duration_s
    infeasible = 0
    fall: tuple[float, np.ndarray] | None = None  # (time, the capture point's way out of the support)
    held_cop = np.full(2, np.nan)  # the CoP the torques held since the last control step were planned for
    thorax, xfrc, geom_xpos = ch.thorax_body, d.xfrc_applied, d.geom_xpos
    sensors = d.sensordata[:n_pts]  # the foot points' touch sensors (a view: the data's buffer is fixed)
    pushing = False
    for k in range(out.touch_n.shape[0]):
        t, control = k * dt, k % every == 0
        if prop is not None and fall is None:
            prop.step(t, control)
        if control:
            i = k // every
            touch = sensors.copy()
            xy = geom_xpos[points, :2]
            cop = spatial_loop.executed_cop(touch, xy)
            out.com_m[i], out.cop_xy_m[i], out.plan_cop_xy_m[i], out.qpos[i] = d.subtree_com[1], cop, held_cop, d.qpos
            out.margin_m[i], out.planted_xy_m[i], out.joint_speed_rad_s[i] = spatial_loop.sample(
                cop, touch, xy, d.qvel, acts, PLANTED_FORCE_N)
            if fall is None and t >= SETTLE_S - 1e-12:  # judged once the first contacts have settled: a pose
                fall = _fallen(m, d, t, touch, prop)  # placed just on the floor touches with no force at first
                if fall is not None:
                    _protective(m, d)
                    if prop is not None:
                        prop.judge(dt)  # a fall freezes the prop's verdict
            if fall is None:
                on_floor = geom_xpos[points, 2] - FOOT_POINT_RADIUS_M < CONTACT_HEIGHT_M  # the planar rule
                plan = _planned(ctl, d, on_floor, table.at(i), prop)
                infeasible += ctl.infeasible
                if plan is None:  # no plan at all, even past the motors' limits: the body is lost - scored as a
                    fall = (t, np.zeros(2))  # fall (penalised), not a crash of the search
                    _protective(m, d)
                    if prop is not None:
                        prop.judge(dt)
                else:
                    d.ctrl[:] = plan.torque_nm
                    held_cop = plan.cop_xy_m
            if fall is not None:
                held_cop = np.full(2, np.nan)
            out.ctrl_nm[i] = d.ctrl
        if (inputs.push_start_s <= t < push_end) != pushing:  # the push starts or ends
            pushing = not pushing
            xfrc[thorax, :3] = push if pushing else 0.0
        mujoco.mj_step(m, d)
        out.touch_n[k] = sensors
        if prop is not None:
            prop.record()
    return fall, infeasible


def _clip_start(inputs: ClipInputs) -> tuple[mujoco.MjModel, mujoco.MjData, PropClip | None]:
    """A clip's own model (protective mode and a prop change it) and data at its start pose, its prop in place
    before the first forward."""
    ch, held = character(BODY), inputs.held
    if held is None:
        m, d = _clip_pair()
    else:
        m = copy.deepcopy(held.model)
        d = mujoco.MjData(m)
    d.qpos[:ch.model.nq] = inputs.start_qpos
    prop = PropClip(held, m, d) if held is not None else None
    mujoco.mj_forward(m, d)
    return m, d, prop


def _clip_pair() -> tuple[mujoco.MjModel, mujoco.MjData]:
    """A clip without a prop's model and data, one pair per thread, reset: the body's model with the protective
    mode's arrays (a fall writes them) restored from the body's, the data ``mj_resetData``'s - what a fresh copy
    and a new MjData are (tests/sim/test_spatial_loop.py), without the 0.5 ms they cost a clip."""
    ch = character(BODY)
    if not hasattr(_local, "clip"):
        model = copy.deepcopy(ch.model)
        _local.clip = (model, mujoco.MjData(model))
    m, d = _local.clip
    for name in ("jnt_stiffness", "dof_damping", "qpos_spring"):
        getattr(m, name)[:] = getattr(ch.model, name)
    mujoco.mj_resetData(m, d)
    return m, d


def replay_3d(r: StandResult, com_out: np.ndarray | None = None) -> int:
    """Step ``r``'s clip again open loop: its recorded torques at each control step (held in between), its push,
    its prop's own per-step behaviour and, from its fall, the protective mode - the clip's physics alone, what
    ``cmrt bench`` times as the floor (a clip without a prop in compiled code, as it ran: ``spatial_loop``).
    ``com_out`` (n, 3): filled with the CoM at each of ``r``'s samples (not while timing; it equals ``r.com_m`` when
    the replay is the clip). Returns the physics steps taken."""
    inputs, ch = r.inputs, character(BODY)
    m, d, prop = _clip_start(inputs)
    push = np.asarray(inputs.push_n, float)
    fall_sample = -1 if r.fall_time_s is None else int(np.searchsorted(r.time_s, r.fall_time_s - 1e-12))
    steps, every, dt = int(round(inputs.clip_s / m.opt.timestep)), inputs.control_every, m.opt.timestep
    window = (inputs.push_start_s, inputs.push_start_s + inputs.push_duration_s)
    c = mjc.c_functions()
    if prop is None and c is not None:
        return spatial_loop.replay_clip(
            c.step, (m._address, d._address), (d.qpos, d.ctrl, d.xfrc_applied, d.subtree_com),
            (steps, every, dt, push, *window, ch.thorax_body), np.ascontiguousarray(r.ctrl_nm), fall_sample,
            _protective_parts(m), np.zeros((0, 3)) if com_out is None else com_out)
    for k in range(steps):
        t, control = k * dt, k % every == 0
        sample = k // every
        if prop is not None and (fall_sample < 0 or k <= fall_sample * every):  # a fall stops the prop's logic
            prop.step(t, control)
        if control:
            if com_out is not None:
                com_out[sample] = d.subtree_com[1]
            if sample == fall_sample:
                _protective(m, d)
            d.ctrl[:] = r.ctrl_nm[sample]
        d.xfrc_applied[ch.thorax_body, :3] = push if window[0] <= t < window[1] else 0.0
        mujoco.mj_step(m, d)
    return steps


def _planned(ctl: SpatialController, d: mujoco.MjData, loaded: np.ndarray, targets: SpatialTargets,
             prop: PropClip | None) -> SpatialPlan | None:
    """The control step's plan, a held prop's load on the hands known to it and the CoM target moved by the share
    of a held mass the controller balances (``prop3d.balancing_held``); None where the QP has no solution at all."""
    try:
        return _plan_for(ctl, d, loaded, targets, prop)
    except CmrtError:
        ctl.infeasible = True
        return None


def _plan_for(ctl: SpatialController, d: mujoco.MjData, loaded: np.ndarray, targets: SpatialTargets,
              prop: PropClip | None) -> SpatialPlan:
    """``_planned``'s plan; raises CmrtError where the QP has no solution."""
    if prop is None:
        return ctl.plan(d, loaded, targets)
    held = prop.held()
    if held is not None and targets.com_xy_m is not None:
        x = balancing_held(float(targets.com_xy_m[0]), ctl.mass_kg, held)
        targets = replace(targets, com_xy_m=np.array([x, targets.com_xy_m[1]]))
    if held is not None:  # a gripped ball: carried in the plan, its inertia known
        return ctl.plan(d, loaded, targets, held_mass=prop.carried(held[0]))
    return ctl.plan(d, loaded, targets, prop.load(ctl.nv))


def _finished(m: mujoco.MjModel, d: mujoco.MjData, ctl: SpatialController, out: ClipSamples,
              outcome: tuple[tuple[float, np.ndarray] | None, int], push_start_s: float,
              prop: PropClip | None) -> StandResult:
    """The clip's result from its samples and its outcome (the fall, the infeasible steps), the prop's verdict and
    figures with it."""
    fall, infeasible = outcome
    time_s = np.arange(0, out.touch_n.shape[0], ctl.config.control_every) * m.opt.timestep  # k x dt, as stepped
    mujoco.mj_subtreeVel(m, d)
    impacts = (push_start_s,)
    if prop is not None:
        prop.judge(m.opt.timestep)
        force = np.array(prop.force_n)
        first = contact_summary(force, force_times_s(force.size, m.opt.timestep), np.ones(force.size, bool))
        impacts += (first["first_contact_s"],) if first["first_contact_s"] is not None else ()
    result = _result((time_s, out.qpos, out.com_m), (out.cop_xy_m, out.plan_cop_xy_m, out.margin_m), fall, impacts,
                     infeasible, float(np.linalg.norm(d.subtree_linvel[1])))
    if prop is not None:
        result = replace(result, prop_goal=prop.goal, prop_force_n=np.array(prop.force_n),
                         prop_extras=tuple(prop.extras.items()))
    ground = out.touch_n.sum(axis=1)
    step_t = np.arange(len(ground)) * m.opt.timestep + m.opt.timestep  # each total is after its step
    return _with_body_figures(result, (step_t, ground / (ctl.mass_kg * GRAVITY_M_S2)), out.planted_xy_m,
                              out.joint_speed_rad_s, impacts)


def _outside_impacts(t: np.ndarray, impacts: tuple[float, ...]) -> np.ndarray:
    """The samples judged: after the first contacts settle and outside ``IMPACT_WINDOW_S`` from each impact's start
    (a push, the hands' first contact with a prop)."""
    keep = t >= SETTLE_S
    for start in impacts:
        keep &= (t < start) | (t >= start + IMPACT_WINDOW_S)
    return keep


def _with_body_figures(r: StandResult, ground: tuple[np.ndarray, np.ndarray], planted_xy: np.ndarray,
                       joint_speed: np.ndarray, impacts: tuple[float, ...]) -> StandResult:
    """``r`` with the planar clips' physical figures (outside the first 0.1 s and the impacts' windows, before a
    fall): peak ground force (body weights, every physics step), time with no foot on the floor, the fastest
    joint, and how far a planted point slid (a point carrying ``PLANTED_FORCE_N`` or more, from where it was first
    planted until it lets go; ``planted_xy``: (n, points, 2), NaN where unplanted); the ``ground_force`` and
    ``airborne`` rules join the verdict."""
    def judged(t: np.ndarray) -> np.ndarray:
        keep = _outside_impacts(t, impacts)
        return keep & (t < r.fall_time_s) if r.fall_time_s is not None else keep

    step_t, bw = ground
    peak = float(bw[judged(step_t)].max()) if judged(step_t).any() else float("nan")
    airborne = float((bw[judged(step_t)] <= 0.0).sum() * (step_t[1] - step_t[0])) if len(step_t) > 1 else 0.0
    sample = judged(r.time_s)
    slide = _planted_slide_m(planted_xy[sample])
    failed = list(r.failed_rules)
    extra = [rule for rule, broken in (("ground_force", not peak <= MAX_GROUND_FORCE_BW),
                                       ("airborne", airborne > MAX_AIRBORNE_S)) if broken]
    at = failed.index("cop_margin") if "cop_margin" in failed else len(failed)
    failed[at:at] = extra  # the planar verdict's order
    return replace(r, peak_normal_force_bw=peak, airborne_s=airborne,
                   max_joint_speed_rad_s=float(joint_speed[sample].max()) if sample.any() else float("nan"),
                   max_foot_slip_m=slide, failed_rules=tuple(failed))


def _planted_slide_m(planted_xy: np.ndarray) -> float:
    """How far any point slid while planted: ``planted_xy`` (samples, points, 2), NaN where a point is not planted;
    each run of planted samples measured from its first (``spatial_loop.planted_slide``)."""
    return float(spatial_loop.planted_slide(np.ascontiguousarray(planted_xy, dtype=float)))


_LIMITS = BalanceLimits()
# what ``spatial_loop.fall_rules`` reads: the cos of the roll limit, the capture margin (m), the CoM height (m), g
_LIMITS_VECTOR = np.array([np.cos(_LIMITS.roll_rad), _LIMITS.capture_margin_m, _LIMITS.com_height_m, GRAVITY_M_S2])


@functools.cache
def _feet() -> tuple[np.ndarray, np.ndarray]:
    """The feet's bodies, and each foot's sole (its point geoms; the right foot's first)."""
    ch = character(BODY)
    return np.array(ch.foot_bodies, dtype=np.int64), np.array([list(pair) for pair in ch.foot_points], dtype=np.int64)


def _fallen(m: mujoco.MjModel, d: mujoco.MjData, t: float, touch: np.ndarray, prop: PropClip | None = None
            ) -> tuple[float, np.ndarray] | None:
    """The planar monitor's rules in 3D (``cmrt.sim.balance``): a foot rolled more than ``roll_rad`` off level, the
    capture point more than ``capture_margin_m`` outside the support - the whole sole of every foot that touches,
    as the planar support spans heel to toe (a foot on its toe comes back down flat while the capture point is
    over its sole) - or the CoM below ``com_height_m``. Returns (now, the capture point's offset from the support's
    centre) on a fall, else None. A held mass the body does not carry counts in the CoM (``prop3d.with_held``); hands
    on a prop that holds the body up (a slab) suspend the capture point's rule, as on the planar body."""
    mujoco.mj_subtreeVel(m, d)
    com, vel = d.subtree_com[1], d.subtree_linvel[1]
    if prop is not None:
        com, vel = with_held(com, vel, float(m.body_subtreemass[1]), prop.held())
    feet, soles = _feet()
    fell, offset = spatial_loop.fall_rules(com, vel, touch, d.geom_xpos, soles, d.xmat, feet,
                                           prop is not None and prop.leaning(), _LIMITS_VECTOR)
    return (t, offset) if fell else None


def _protective_parts(m: mujoco.MjModel) -> tuple[np.ndarray, ...]:
    """The planar protective mode (``cmrt.sim.monitor``) for ``spatial_loop.protect``: motors off, every actuated
    joint a passive spring and damper about the pose it fell in (0.1 x its motor's limit per rad and per rad/s),
    integrated by MuJoCo - (the joints, their dofs, their qpos, the stiffness and damping, and the clip's own model's
    arrays they go into)."""
    joints, limit = m.actuator_trnid[:, 0], character(BODY).torque_limit_nm
    return (joints.astype(np.int64), m.jnt_dofadr[joints].astype(np.int64), m.jnt_qposadr[joints].astype(np.int64),
            PROTECTIVE_STIFFNESS_PER_RAD * limit, PROTECTIVE_DAMPING_PER_RAD_S * limit, m.jnt_stiffness,
            m.dof_damping, m.qpos_spring)


def _protective(m: mujoco.MjModel, d: mujoco.MjData) -> None:
    """The protective mode a fall starts (``_protective_parts``), from Python."""
    spatial_loop.protect(_protective_parts(m), d.qpos, d.ctrl)


def _margin(cop: np.ndarray, touching_xy: np.ndarray) -> float:
    """How far ``cop`` is inside the convex hull of the touching points (m; negative outside, 0 on a line or with
    fewer than three points). The hull's edges are the point pairs with every point on one side; for the eight
    foot points this is quicker than qhull (``scipy.spatial.ConvexHull``, 0.45 ms a call: two calls a control
    step made it 40 % of a leg lift's clip) and the same to rounding (a test); compiled, as numpy's 15 calls cost
    60 us a call - a fifth of a clip's time before its QP was written in blocks."""
    cop = np.asarray(cop, float)
    return spatial_loop.hull_margin(cop[0], cop[1], np.ascontiguousarray(touching_xy, dtype=float).reshape(-1, 2))


def _result(motion: tuple[np.ndarray, np.ndarray, np.ndarray], cops: tuple[np.ndarray, np.ndarray, np.ndarray],
            fall: tuple[float, np.ndarray] | None, impacts: tuple[float, ...], infeasible: int, final_speed: float
            ) -> StandResult:
    """The clip's figures and verdict from its samples (``motion``: times, poses, CoM; ``cops``: executed,
    planned, the executed one's margin; ``fall``: when, and where the capture point left)."""
    time_s, qpos, com = motion
    cop, plan_cop, margin = cops
    judged = _outside_impacts(time_s, impacts)
    fall_time = None if fall is None else fall[0]
    if fall_time is not None:
        judged &= time_s < fall_time
    gap = np.abs(plan_cop - cop)[judged]
    gap = gap[np.isfinite(gap).all(axis=1)]
    direction = None if fall is None else fall[1] / max(float(np.linalg.norm(fall[1])), 1e-12)
    max_gap = float(gap.max()) if gap.size else float("nan")
    min_margin = float(margin[judged].min()) if judged.any() else float("nan")
    failed = tuple(rule for rule, broken in (
        ("balance", fall_time is not None), ("settled", not final_speed < SETTLED_COM_SPEED_M_S),
        ("plan", not max_gap <= MAX_PLAN_COP_ERROR_M), ("cop_margin", not min_margin >= MIN_COP_MARGIN_M)) if broken)
    topple = com[-1, :2] - com[0, :2]
    return StandResult(time_s, qpos, com, cop, plan_cop, fall_time is not None, fall_time, direction,
                       topple / max(float(np.linalg.norm(topple)), 1e-12) if fall is not None else None, final_speed,
                       max_gap, min_margin, infeasible, failed)


@dataclass(frozen=True)
class LegLiftClip:
    """A leg lift's clip with what its objective and timing rule need."""

    result: StandResult
    foot_lift_m: float  # how high the lifted foot ended above where it stood
    lift_off_s: float  # when the reference lets the foot go
    cop_reference_xy_m: np.ndarray  # (n, 2) the controller's CoP reference at each sample
    q_reference: np.ndarray  # (n, nq) the reference pose at each sample
    com_shift_m: float  # the CoM's move toward the stance foot from the motion's start to lift-off (y, signed)


@dataclass(frozen=True)
class _LegLiftReference:
    """A leg lift's reference without its CMRT - the same for every clip of a task at a speed, so made once: the
    poses, both feet's centre, lift-off, and at every control step (n rows) the targets without the CMRT (its
    ``com_vel_xy_m_s`` the reference's own rate before lift-off, 0 after) and whether the foot is lifting."""

    poses: object
    both_xy_m: np.ndarray
    lift_at_s: float
    table: SpatialTargetTable
    lifting: np.ndarray  # (n,) bool
    foot_start_z_m: float  # the lifted foot's frame's height standing


@functools.lru_cache(maxsize=32)
def _leg_lift_reference(shift_s: float, lift_s: float, clip_s: float, stance: int, start_s: float, reference: str,
                        control_every: int) -> _LegLiftReference:
    """``leg_lift_3d``'s reference (its docstring says what each mode asks); three kinematics passes a control
    step once lifting (the foot's path and its rate by a central difference) were a sixth of a clip's time."""
    poses = one_leg_poses(stand_pose_qpos(), stance)
    ch = character(BODY)
    m, scratch = ch.model, mujoco.MjData(ch.model)
    both = feet_centre_xy(poses.standing)  # both feet's support centre
    foot_body, lift_at_s = ch.foot_bodies[1 - stance], start_s + shift_s

    def reference_of(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        scratch.qpos[:] = q
        mujoco.mj_kinematics(m, scratch)
        mujoco.mj_comPos(m, scratch)
        return scratch.subtree_com[1, :2].copy(), scratch.xpos[foot_body].copy()

    standing_com, shifted_com = reference_of(poses.standing)[0], reference_of(poses.shifted)[0]

    def eased(t: float, t0: float, span: float, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, ...]:
        return _eased(m, (t - t0) / span, span, a, b)

    def at(t: float) -> tuple:
        if t < lift_at_s:
            q, qd, qdd = eased(t, start_s, shift_s, poses.standing, poses.shifted)
            u = (t - start_s) / shift_s
            a, rate = _smoothstep(u), _smoothstep_rate(u) / shift_s
            if reference == "center":
                return q, qd, qdd, both.copy(), np.zeros(2), both, None, None
            return (q, qd, qdd, reference_of(q)[0], rate * (shifted_com - standing_com),
                    both + a * (poses.stance_centre_xy_m - both), None, None)
        q, qd, qdd = eased(t, lift_at_s, lift_s, poses.shifted, poses.lifted)
        com, foot = reference_of(q)
        foot_vel = np.diff([reference_of(eased(t + e, lift_at_s, lift_s, poses.shifted, poses.lifted)[0])[1]
                            for e in (-1e-3, 1e-3)], axis=0)[0] / 2e-3  # the foot path's rate: a central difference
        centre = poses.stance_centre_xy_m
        return q, qd, qdd, centre if reference == "center" else com, None, centre, foot, foot_vel

    rows = [at(t) for t in control_times_s(clip_s, control_every).tolist()]
    lifting = np.array([row[6] is not None for row in rows])

    def column(j: int, width: int) -> np.ndarray:
        return np.array([row[j] if row[j] is not None else np.zeros(width) for row in rows], dtype=float)
    table = SpatialTargetTable(column(3, 2), column(4, 2), column(5, 2), column(0, 0), column(1, 0), column(2, 0),
                               np.where(lifting, 1 - stance, -1), column(6, 3), column(7, 3))
    return _LegLiftReference(poses, both, lift_at_s, table, lifting, float(reference_of(poses.standing)[1][2]))


def leg_lift_3d(shift_s: float = 1.5, lift_s: float = 0.8, clip_s: float = 5.0, stance: int = 1,
                config: ControllerConfig = ControllerConfig(), cmrt_y: Cmrt | None = None, start_s: float = 0.5,
                reference: str = "yu", push: tuple[tuple[float, float, float], float, float] | None = None,
                cmrt_x: Cmrt | None = None) -> LegLiftClip:
    """The 3D body shifting its weight onto the ``stance`` foot over ``shift_s`` (from ``start_s``; both feet
    down), then lifting the other foot 10 cm over ``lift_s`` and standing on one leg to ``clip_s`` - the reference
    pose moving through ``cmrt.body.one_leg``'s poses. The CoM's and CoP's references (``reference``):

    * "center", the paper's: the support's centre - both feet, then the stance foot from lift-off - the CoM's
      displaced sideways by the CMRT ``cmrt_y``: the controller learns of the new support at lift-off, and only
      the CMRT can shift the weight before it;
    * "yu", the reference motion's own weight shift (Yu's references are the reference's loaded feet): the CoM's
      the reference poses' (plus the CMRT), the CoP's moving from both feet onto the stance foot with the shift.

    ``push``: (force on the thorax, N; its start, s; its duration, s), as ``stand_3d``'s; ``cmrt_x``: a two-axis
    CMRT's forward part (``Cmrt.cross``)."""
    ref = _leg_lift_reference(shift_s, lift_s, clip_s, stance, start_s, reference, config.control_every)
    poses, both, lift_at_s, swing = ref.poses, ref.both_xy_m, ref.lift_at_s, 1 - stance
    ch = character(BODY)
    m, scratch = ch.model, _scratch()
    foot_body, up = ch.foot_bodies[swing], np.array([0.0, 1.0])
    curve = cmrt_y if cmrt_y is not None else Cmrt.zero(clip_s)
    shift_m, shift_m_s = _sampled(curve, clip_s, config.control_every)
    own = ref.table
    lifting = ref.lifting[:, None]  # from lift-off the CoM's rate is the CMRT's alone
    table = replace(own, com_xy_m=own.com_xy_m + shift_m[:, None] * up,
                    com_vel_xy_m_s=np.where(lifting, shift_m_s[:, None] * up,
                                            own.com_vel_xy_m_s + shift_m_s[:, None] * up))
    table = _crossed(table, cmrt_x, clip_s, config.control_every, np.array([1.0, 0.0]))
    force, push_start_s, push_duration_s = push if push is not None else ((0.0, 0.0, 0.0), clip_s, 0.1)
    result = stand_3d(clip_s=clip_s, push_n=force, push_start_s=push_start_s, push_duration_s=push_duration_s,
                      config=config, motion=table)
    scratch.qpos[:] = result.qpos[-1]
    mujoco.mj_kinematics(m, scratch)
    k0 = int(np.searchsorted(result.time_s, start_s - 1e-9))
    k1 = max(int(np.searchsorted(result.time_s, lift_at_s - 1e-9)) - 1, k0)
    toward = 1.0 if poses.stance_centre_xy_m[1] > both[1] else -1.0
    return LegLiftClip(result, float(scratch.xpos[foot_body][2] - ref.foot_start_z_m), lift_at_s,
                       table.cop_xy_m.copy(), table.q_ref.copy(),
                       toward * float(result.com_m[k1, 1] - result.com_m[k0, 1]))


def pose_change_3d(reference: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]],
                   start_qpos: np.ndarray, clip_s: float, cmrt_x: Cmrt, config: ControllerConfig = ControllerConfig(),
                   push: tuple[tuple[float, float, float], float, float] | None = None, held: HeldProp | None = None,
                   cmrt_y: Cmrt | None = None) -> tuple[StandResult, np.ndarray]:
    """The 3D body moving through ``reference`` (times (n,) -> q (n, nq), qd and qdd (n, nv): its pose, tracked
    with the rates fed forward) from ``start_qpos``, both feet down, in the paper's centre mode: the CoM's and
    CoP's reference the feet's centre, the CoM's displaced forward by the CMRT ``cmrt_x`` (and sideways by a
    two-axis CMRT's ``cmrt_y``, +y to the left). Returns the clip and the reference pose at its samples. ``push`` as
    ``leg_lift_3d``'s, ``held`` as ``stand_3d``'s."""
    centre = feet_centre_xy(start_qpos)
    forward = np.array([1.0, 0.0])
    times = control_times_s(clip_s, config.control_every)
    q, qd, qdd = reference(times)  # the reference at every control step at once
    shift_m, shift_m_s = _sampled(cmrt_x, clip_s, config.control_every)
    n = times.size
    table = SpatialTargetTable(centre + shift_m[:, None] * forward, shift_m_s[:, None] * forward,
                               np.broadcast_to(centre, (n, 2)), q, qd, qdd)
    motion = _crossed(table, cmrt_y, clip_s, config.control_every, np.array([0.0, 1.0]))
    force, push_start_s, push_duration_s = push if push is not None else ((0.0, 0.0, 0.0), clip_s, 0.1)
    result = stand_3d(clip_s=clip_s, push_n=force, push_start_s=push_start_s, push_duration_s=push_duration_s,
                      config=config, motion=motion, start_qpos=start_qpos, held=held)
    return result, reference(result.time_s)[0]


def _crossed(table: SpatialTargetTable, curve: Cmrt | None, clip_s: float, control_every: int, axis: np.ndarray
             ) -> SpatialTargetTable:
    """A two-axis CMRT's second displacement (``Cmrt.cross``) along ``axis`` (a unit xy vector) added to the CoM's
    reference and its rate at every control step; None: the table as it is (a one-axis CMRT's clip, bit for bit)."""
    if curve is None:
        return table
    shift_m, shift_m_s = _sampled(curve, clip_s, control_every)
    return replace(table, com_xy_m=table.com_xy_m + shift_m[:, None] * axis,
                   com_vel_xy_m_s=table.com_vel_xy_m_s + shift_m_s[:, None] * axis)


def _sampled(curve: Cmrt, clip_s: float, control_every: int) -> tuple[np.ndarray, np.ndarray]:
    """The CMRT's displacement (m) and rate (m/s) at every control step."""
    times = control_times_s(clip_s, control_every)
    return np.asarray(curve.displacement_m(times), float), np.asarray(curve.velocity_m_s(times), float)


def control_times_s(clip_s: float, control_every: int) -> np.ndarray:
    """The times of a clip's control steps (s), as ``stand_3d`` computes them (step index x the model's step)."""
    dt = character(BODY).model.opt.timestep
    return np.arange(0, int(round(clip_s / dt)), control_every) * dt


def _eased(m: mujoco.MjModel, u: float, span_s: float, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, ...]:
    """The pose eased from ``a`` to ``b`` at ``u`` of its ``span_s``, with its joints' rate and acceleration (nv;
    the root's left 0: the controller tracks the actuated joints)."""
    act_q, act_v = m.jnt_qposadr[m.actuator_trnid[:, 0]], m.jnt_dofadr[m.actuator_trnid[:, 0]]
    rate, accel = np.zeros(m.nv), np.zeros(m.nv)
    if 0.0 < u < 1.0:
        rate[act_v] = 6.0 * u * (1.0 - u) / span_s * (b - a)[act_q]
        accel[act_v] = (6.0 - 12.0 * u) / span_s**2 * (b - a)[act_q]
    return a + _smoothstep(u) * (b - a), rate, accel


def _smoothstep(u: float) -> float:
    u = min(max(u, 0.0), 1.0)
    return u * u * (3.0 - 2.0 * u)


def _smoothstep_rate(u: float) -> float:
    return 6.0 * u * (1.0 - u) if 0.0 < u < 1.0 else 0.0


def cop_error_objective(result: StandResult, reference_xy: np.ndarray, sample_s: float = 0.01) -> float:
    """The paper's objective on a 3D clip: the 2-norm of the executed CoP's error from ``reference_xy`` ((n, 2),
    at the clip's samples), as if sampled every ``sample_s``, plus the planar objective's penalties: for a fall
    ``FALL_PENALTY`` (10) and up to 10 more the earlier it came (a slope for the optimizer), or, standing but not a
    success, its penalty for a motion a researcher would not accept (``NOT_PLAUSIBLE_PENALTY`` x (1 + the plan
    gap's excess over its bound, up to 1): 5-10). So a fall always scores worse than a stand; with 5 and up to 5
    more (this objective's first fall penalty) a fall at the clip's end outscored a stand 1 mm past the plan's
    bound, and searches settled there (leg-lift seeds 4 and 5 in 1,000 evaluations each, the 3D punch). A sample
    with no CoP counts 0.3 m per axis."""
    err = np.nan_to_num(result.cop_xy_m - reference_xy, nan=0.3)
    dt = float(result.time_s[1] - result.time_s[0]) if len(result.time_s) > 1 else sample_s
    value = float(np.linalg.norm(err)) * np.sqrt(dt / sample_s)
    if result.fell:
        span_s = float(result.time_s[-1] + dt)
        value += FALL_PENALTY + 10.0 * max(span_s - result.fall_time_s, 0.0) / span_s
    elif result.failed_rules:
        excess = (result.max_plan_cop_error_m - MAX_PLAN_COP_ERROR_M) / MAX_PLAN_COP_ERROR_M
        value += NOT_PLAUSIBLE_PENALTY * (1.0 + min(max(excess, 0.0), 1.0))
    return value
