"""Clips -> trajectories (CoM, CoP, support, contacts, balance loss), many at once.

``simulate_batch`` steps n clips of one task that differ only in their CMRT in lockstep
on a ``mujoco.batch.Batch`` (C thread pool) with one vectorised controller; ``simulate``
is the case n = 1. MuJoCo's batch is bit-identical to stepping each simulation alone,
and the controller's arithmetic is row-wise, so a candidate's objective does not
depend on what else is in its batch (tested).

A clip always starts from the task's settled standing state: the start pose held by
the controller for ``SETTLE_S`` seconds, so no start-up transient enters the objective.
Balance loss is detected physically at every control step (8 ms):

* a body other than the heel/toe points reaches the floor (its lowest point below
  z = 0), or the CoM drops below ``FALL_COM_HEIGHT_M``  -> a fall (the clip stops);
* a heel or toe point rises more than ``LIFT_THRESHOLD_M`` above its settled height
  -> the foot tipped (the clip goes on until the lift reaches ``LIFT_STOP_M`` so the
  penalty can grade how badly it tipped);
* non-finite state or a MuJoCo instability reset -> a numerical blow-up.
A finished simulation is masked out of the batch; none of these raises.

The CoP is measured from the contact forces MuJoCo applied during each step: touch
sensors around the four heel/toe spheres read each point's normal force f_i, the
contact lies straight under the sphere's centre x_i, so ``cop_x = sum f_i x_i / sum f_i``.
Forces on the hands (a ball, a bag, a slab) never enter it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import mujoco
import mujoco.batch
import numpy as np

from cmrt.character import character
from cmrt.control import ControllerConfig, MomentumBalanceController
from cmrt.curve import Cmrt
from cmrt.props import PropRuntime
from cmrt.task import Task

SETTLE_S = 1.5
LIFT_THRESHOLD_M = 0.01  # heel/toe lift that counts as the foot tipping
LIFT_STOP_M = 0.21  # lift at which a tipped clip is cut short (penalty saturates)
FALL_COM_HEIGHT_M = 0.55  # standing CoM is ~0.97 m, the deepest task pose ~0.8 m

CONTROL_FIELDS = ("qpos", "qvel", "cdof", "cdof_dot", "cvel", "cinert", "M", "qfrc_bias", "qfrc_passive",
                  "subtree_com", "xpos", "geom_xpos")
STATE_FIELDS = ("qpos", "qvel", "qacc_warmstart")


@dataclass(frozen=True)
class Trajectory:
    """Per-physics-step record of a clip; time-aligned arrays (n_steps, ...)."""

    time_s: np.ndarray
    qpos: np.ndarray  # NaN-filled unless recorded
    qvel: np.ndarray
    com_m: np.ndarray  # (n, 2): x, z
    cop_x_m: np.ndarray  # measured from the contact forces; NaN when the feet carry no load
    support_center_x_m: np.ndarray
    support_lo_x_m: np.ndarray
    support_hi_x_m: np.ndarray
    normal_force_n: np.ndarray  # total vertical ground force
    foot_normal_force_n: np.ndarray  # (n, 2): right, left
    point_lift_m: np.ndarray  # (n, 4): heel_r, toe_r, heel_l, toe_l above settled height
    cmrt_displacement_m: np.ndarray
    com_ref_x_m: np.ndarray
    ctrl_nm: np.ndarray
    fell: bool
    fall_time_s: float | None
    fall_reason: str | None
    diverged: bool
    max_lift_m: float
    final_qpos: np.ndarray  # the humanoid's
    task_success: bool | None = None  # goal reached (ball caught and held, slab toppled, target hit)

    def as_npz_dict(self) -> dict[str, np.ndarray]:
        out = {k: v for k, v in self.__dict__.items() if isinstance(v, np.ndarray)}
        out["fell"] = np.array(self.fell)
        out["diverged"] = np.array(self.diverged)
        out["fall_time_s"] = np.array(np.nan if self.fall_time_s is None else self.fall_time_s)
        out["task_success"] = np.array(np.nan if self.task_success is None else float(self.task_success))
        return out


class _Geometry:
    """Constant per-model data for the balance-loss checks."""

    def __init__(self):
        ch = character()
        m = ch.model
        self.points = np.array(ch.foot_point_geoms)
        feet = set(ch.foot_point_geoms) | {ch.floor_geom}
        body = [g for g in range(m.ngeom) if g not in feet and m.geom_conaffinity[g] and m.geom_type[g]
                == mujoco.mjtGeom.mjGEOM_CAPSULE]
        self.body_geoms = np.array(body)
        self.radius = m.geom_size[body, 0]
        self.half = m.geom_size[body, 1]

    def lowest_body_z(self, geom_xpos: np.ndarray, geom_xmat: np.ndarray) -> np.ndarray:
        """Lowest point of any non-foot capsule, per simulation."""
        z = geom_xpos[:, self.body_geoms, 2] - np.abs(geom_xmat[:, self.body_geoms, 8]) * self.half - self.radius
        return z.min(axis=1)


_SETTLED: dict = {}


def _threads(n: int) -> int:
    return max(1, min(n, int(os.environ.get("CMRT_THREADS", os.cpu_count() or 1))))


def settled_state(task: Task, config: ControllerConfig) -> dict[str, np.ndarray]:
    """The start pose after the controller held it for SETTLE_S (cached per process and model)."""
    from cmrt.props import model_values

    q0 = task.start_qpos()
    key = (q0.tobytes(), config, task.prop, model_values(task.prop, task.params))
    if key not in _SETTLED:
        ch = character()
        m = task.model()
        prop = PropRuntime(task.prop, m, task.params)
        batch = mujoco.batch.Batch(m, nsim=1, nthread=1, persistent=True)
        f = {k: batch.bind(k) for k in set(CONTROL_FIELDS) | set(STATE_FIELDS) | {"ctrl"}}
        f["qpos"][0, : q0.size] = q0
        f["qpos"][0, 1] -= 0.002  # start just in contact: the feet sink ~2 mm under body weight
        batch.forward(stage=mujoco.mjtStage.mjSTAGE_VEL)
        ctrl = MomentumBalanceController(ch, config)
        lo, hi = _support(f["geom_xpos"], np.array(ch.foot_point_geoms))
        center = 0.5 * (lo + hi)
        zeros = np.zeros(q0.size)
        for k in range(int(round(SETTLE_S / m.opt.timestep))):
            if k % config.control_every == 0:
                f["ctrl"][:] = ctrl.torques(f, q0, zeros, zeros, center, np.zeros(1), center)
            prop.settle_hold(f)
            batch.step(stage=mujoco.mjtStage.mjSTAGE_VEL)
        _SETTLED[key] = {k: f[k][0].copy() for k in STATE_FIELDS}
    return _SETTLED[key]


def _support(geom_xpos: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    xs = geom_xpos[:, points, 0]
    return xs.min(axis=1), xs.max(axis=1)


def _control(controller, f, k, q_ref, qd_ref, qdd_ref, com_ref, com_ref_vel, center):
    """Torques for the given rows; a row whose plan is singular or non-finite gets zeros and bad=True."""
    args = (q_ref[k], qd_ref[k], qdd_ref[k])
    with np.errstate(all="ignore"):
        try:
            ctrl = controller.torques(f, *args, com_ref, com_ref_vel, center)
        except np.linalg.LinAlgError:  # find the culprits one by one; the others are unaffected
            ctrl = np.full((com_ref.size, controller.limits.size), np.nan)
            for i in range(com_ref.size):
                fi = {name: v[i : i + 1] for name, v in f.items()}
                try:
                    ctrl[i] = controller.torques(fi, *args, com_ref[i : i + 1], com_ref_vel[i : i + 1],
                                                 center[i : i + 1])[0]
                except np.linalg.LinAlgError:
                    pass
    bad = ~np.all(np.isfinite(ctrl), axis=1)
    ctrl[bad] = 0.0
    return ctrl, bad


def simulate_batch(
    task: Task,
    curves: list[Cmrt | None],
    config: ControllerConfig = ControllerConfig(),
    record: bool = False,
    threads: int | None = None,
) -> list[Trajectory]:
    """Simulate one clip of ``task`` per CMRT (None: zero CMRT), in lockstep.

    ``record`` also fills qpos, qvel and the CoP at every step (for traces); scores do
    not depend on it. ``threads``: MuJoCo batch threads (default: all cores,
    or $CMRT_THREADS).
    """
    ch = character()
    m = task.model()
    n = len(curves)
    dt = m.opt.timestep
    n_steps = int(round(task.clip_s / dt))
    times = np.arange(n_steps) * dt
    curves = [c or Cmrt.zero(task.clip_s) for c in curves]
    disp = np.stack([c.displacement_m(times) for c in curves])  # (n, T)
    disp_vel = np.stack([c.velocity_m_s(times) for c in curves])
    q_ref, qd_ref, qdd_ref = task.reference(times)
    push = np.array([task.push_at(t) for t in times])
    geo = _Geometry()
    controller = MomentumBalanceController(ch, config)
    vel_stage = mujoco.mjtStage.mjSTAGE_VEL

    batch = mujoco.batch.Batch(m, nsim=n, nthread=threads or _threads(n), persistent=True)
    prop = PropRuntime(task.prop, m, task.params)
    names = set(CONTROL_FIELDS) | set(STATE_FIELDS) | {"ctrl", "xfrc_applied", "sensordata", "geom_xmat", "time"}
    b = {k: batch.bind(k) for k in names | prop.fields()}
    for k, v in settled_state(task, config).items():
        b[k][:] = v
    b["time"][:] = 0.0
    prop.start(batch, b)
    batch.forward(stage=vel_stage)
    settled_z = b["geom_xpos"][0, geo.points, 2].copy()

    def buf(*shape):
        return np.full((n, n_steps, *shape), np.nan)

    nq = ch.model.nq  # the humanoid's coordinates come first; a prop's follow them
    rec = {"com": buf(2), "cop": buf(), "sc": buf(), "lo": buf(), "hi": buf(), "fz": buf(), "lift": buf(4),
           "cref": buf(), "ctrl": buf(m.nu), "qpos": buf(m.nq), "qvel": buf(m.nv), "ffz": buf(2)}
    last = np.full(n, n_steps)
    fell = np.zeros(n, bool)
    diverged = np.zeros(n, bool)
    fall_time = np.full(n, np.nan)
    reasons: list[str | None] = [None] * n
    max_lift = np.zeros(n)
    active = np.arange(n)

    ctrl_all = np.zeros((n, m.nu))
    bad_all = np.zeros(n, bool)
    sample_every = max(1, int(round(task.cop_sample_step_s / dt)))
    all_ids = np.arange(n)
    for k in range(n_steps):
        # Work happens on control steps (balance checks too), CoP sample steps, or every step
        # when recording a trace; in between, the batch just steps (the cost floor).
        control = k % config.control_every == 0
        sample = record or k % sample_every == 0
        whole = active.size == n
        sel = slice(None) if whole else active
        ids = all_ids[sel]
        if control or sample:
            geom_xpos = b["geom_xpos"][sel]
            lo, hi = _support(geom_xpos, geo.points)
            center = 0.5 * (lo + hi)
            rec["sc"][sel, k], rec["lo"][sel, k], rec["hi"][sel, k] = center, lo, hi
            point_x = geom_xpos[:, geo.points, 0]  # heel/toe x at the state the step starts from
        if control:
            prop.control_step(b, ids)
            f = {name: (b[name] if whole else b[name][active]) for name in CONTROL_FIELDS}
            com_ref = center + disp[sel, k]
            ctrl, bad = _control(controller, f, k, q_ref, qd_ref, qdd_ref, com_ref, disp_vel[sel, k], center)
            ctrl_all[sel], bad_all[sel] = ctrl, bad
            b["ctrl"][sel] = ctrl
        if control or record:
            com = b["subtree_com"][sel, 1]
            lift = geom_xpos[:, geo.points, 2] - settled_z
            low_body = geo.lowest_body_z(geom_xpos, b["geom_xmat"][sel])
            rec["com"][sel, k] = com[:, [0, 2]]
            rec["cref"][sel, k] = center + disp[sel, k]
            rec["lift"][sel, k] = lift
            rec["ctrl"][sel, k] = ctrl_all[sel]
        if k == 0 or push[k] != push[k - 1]:
            b["xfrc_applied"][sel, ch.thorax_body, 0] = push[k]
        if record:
            rec["qpos"][sel, k], rec["qvel"][sel, k] = b["qpos"][sel], b["qvel"][sel]

        batch.step(ids=None if whole else active, stage=vel_stage)

        if sample:
            touch = b["sensordata"][sel, : geo.points.size]  # normal force at heel_r, toe_r, heel_l, toe_l
            fz = touch.sum(axis=1)
            with np.errstate(all="ignore"):
                cop = np.where(fz > 1e-9, (touch * point_x).sum(axis=1) / fz, np.nan)
            rec["cop"][sel, k], rec["fz"][sel, k] = cop, fz
            rec["ffz"][sel, k] = np.stack([touch[:, :2].sum(axis=1), touch[:, 2:].sum(axis=1)], axis=1)
        if not control:
            continue

        t_next = b["time"][sel]
        blown = bad_all[sel] | ~np.all(np.isfinite(b["qpos"][sel]), axis=1) | (np.abs(t_next - (k + 1) * dt) > 1e-9)
        hard = (low_body < 0.0) | (com[:, 2] < FALL_COM_HEIGHT_M)
        peak = lift.max(axis=1)
        tipped = peak > LIFT_THRESHOLD_M
        if not (blown.any() or hard.any() or tipped.any() or fell[ids].any()):
            continue
        done = np.zeros(ids.size, bool)
        for i, sim in enumerate(ids):
            if blown[i]:
                diverged[sim] = fell[sim] = True
                if np.isnan(fall_time[sim]):
                    fall_time[sim] = times[k]
                reasons[sim] = "numerical blow-up" + (" (controller)" if bad_all[sim] else "")
                done[i] = True
                continue
            if fell[sim]:
                max_lift[sim] = max(max_lift[sim], peak[i])
            if hard[i]:
                if not fell[sim]:
                    fell[sim], fall_time[sim] = True, times[k]
                    reasons[sim] = ("a body other than the feet touched the floor" if low_body[i] < 0.0
                                    else "CoM dropped too low")
                max_lift[sim] = max(max_lift[sim], LIFT_STOP_M)
                done[i] = True
                continue
            if not fell[sim] and tipped[i]:
                fell[sim], fall_time[sim] = True, times[k]
                reasons[sim] = "a support foot tipped (heel or toe lifted)"
                max_lift[sim] = peak[i]
            if fell[sim] and max_lift[sim] >= LIFT_STOP_M:
                done[i] = True
        if done.any():
            last[ids[done]] = k + 1
            active = ids[~done]
            if active.size == 0:
                break

    final_qpos = b["qpos"][:, :nq].copy()
    success = prop.success(b)
    out = []
    for i in range(n):
        cut = slice(0, last[i])
        out.append(Trajectory(
            time_s=times[cut], qpos=rec["qpos"][i, cut], qvel=rec["qvel"][i, cut], com_m=rec["com"][i, cut],
            cop_x_m=rec["cop"][i, cut], support_center_x_m=rec["sc"][i, cut], support_lo_x_m=rec["lo"][i, cut],
            support_hi_x_m=rec["hi"][i, cut], normal_force_n=rec["fz"][i, cut],
            foot_normal_force_n=rec["ffz"][i, cut], point_lift_m=rec["lift"][i, cut],
            cmrt_displacement_m=disp[i, cut], com_ref_x_m=rec["cref"][i, cut], ctrl_nm=rec["ctrl"][i, cut],
            fell=bool(fell[i]), fall_time_s=None if np.isnan(fall_time[i]) else float(fall_time[i]),
            fall_reason=reasons[i], diverged=bool(diverged[i]), max_lift_m=float(max_lift[i]),
            final_qpos=final_qpos[i], task_success=None if success is None else bool(success[i]),
        ))
    return out


def simulate(
    task: Task, curve: Cmrt | None = None, config: ControllerConfig = ControllerConfig(), record: bool = True
) -> Trajectory:
    """Simulate one clip of ``task`` with CMRT ``curve`` (None: zero CMRT), recording everything."""
    return simulate_batch(task, [curve], config, record=record)[0]
