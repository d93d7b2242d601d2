"""One clip -> trajectories (CoM, CoP, support, contacts, balance loss).

A clip always starts from the task's settled standing state: the start pose held by
the controller for ``SETTLE_S`` seconds, so no start-up transient enters the
objective. Balance loss is detected physically, every physics step:

* a body other than the heel/toe points touches the floor, or the CoM drops below
  ``FALL_COM_HEIGHT_M``  -> a fall (the clip stops there);
* a heel or toe point rises more than ``LIFT_THRESHOLD_M`` above its settled height
  -> the foot tipped (the clip goes on until the lift reaches ``LIFT_STOP_M`` so the
  penalty can grade how badly it tipped);
* non-finite state or a MuJoCo instability warning -> a numerical blow-up.
None of these raises: they are recorded and penalised by the objective.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from cmrt.character import character, support_interval_x
from cmrt.control import ControllerConfig, MomentumBalanceController
from cmrt.curve import Cmrt
from cmrt.task import Task

SETTLE_S = 1.5
LIFT_THRESHOLD_M = 0.01  # heel/toe lift that counts as the foot tipping
LIFT_STOP_M = 0.21  # lift at which a tipped clip is cut short (penalty saturates)
FALL_COM_HEIGHT_M = 0.55  # standing CoM is ~0.97 m, the deepest task pose ~0.8 m


@dataclass(frozen=True)
class Trajectory:
    """Per-physics-step record of a clip; time-aligned arrays (n_steps, ...)."""

    time_s: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    com_m: np.ndarray  # (n, 2): x, z
    cop_x_m: np.ndarray  # measured from contact forces; nan when no foot force
    support_center_x_m: np.ndarray
    support_lo_x_m: np.ndarray
    support_hi_x_m: np.ndarray
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
    final_qpos: np.ndarray

    def as_npz_dict(self) -> dict[str, np.ndarray]:
        out = {k: v for k, v in self.__dict__.items() if isinstance(v, np.ndarray)}
        out["fell"] = np.array(self.fell)
        out["diverged"] = np.array(self.diverged)
        out["fall_time_s"] = np.array(np.nan if self.fall_time_s is None else self.fall_time_s)
        return out


_SETTLED: dict = {}


def settled_state(task: Task, config: ControllerConfig) -> np.ndarray:
    """mjSTATE_INTEGRATION vector of the start pose after settling (cached per process)."""
    ch = character()
    q0 = task.start_qpos()
    key = (q0.tobytes(), config)
    if key in _SETTLED:
        return _SETTLED[key]
    m = ch.model
    d = mujoco.MjData(m)
    d.qpos[:] = q0
    d.qpos[1] -= 0.002  # start just in contact: the feet sink ~2 mm under body weight
    ctrl = MomentumBalanceController(ch, config)
    zeros = np.zeros(m.nv)
    mujoco.mj_forward(m, d)
    lo, hi = support_interval_x(d)
    center = 0.5 * (lo + hi)
    for _ in range(int(round(SETTLE_S / m.opt.timestep))):
        mujoco.mj_step1(m, d)
        d.ctrl[:] = ctrl.torques(d, q0, zeros, zeros, center, 0.0, center)
        mujoco.mj_step2(m, d)
    d.time = 0.0
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    state = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, d, state, spec)
    _SETTLED[key] = state
    return state


def _contact_summary(ch, m, d, force6: np.ndarray) -> tuple[float, float, float, bool]:
    """(CoP x, right foot Fz, left foot Fz, non-foot contact) from this step's contacts."""
    feet = ch.foot_points
    fz_sum = fz_r = fz_l = moment = 0.0
    other = False
    for i in range(d.ncon):
        con = d.contact[i]
        g1, g2 = con.geom1, con.geom2
        gid = g2 if g1 == ch.floor_geom else g1 if g2 == ch.floor_geom else -1
        if gid < 0:
            continue
        if gid not in feet[0] and gid not in feet[1]:
            other = True
            continue
        mujoco.mj_contactForce(m, d, i, force6)
        # frame row 0 is the contact normal (+z on a flat floor), force6[0] the normal
        # force; the friction directions are horizontal, so only the normal adds to Fz.
        fz = float(con.frame[2] * force6[0])
        fz_sum += fz
        moment += fz * con.pos[0]
        if gid in feet[0]:
            fz_r += fz
        else:
            fz_l += fz
    cop = moment / fz_sum if fz_sum > 1e-9 else np.nan
    return cop, fz_r, fz_l, other


def simulate(task: Task, curve: Cmrt | None = None, config: ControllerConfig = ControllerConfig()) -> Trajectory:
    """Simulate one clip of ``task`` with CMRT ``curve`` (None: zero CMRT)."""
    ch = character()
    m = ch.model
    dt = m.opt.timestep
    n = int(round(task.clip_s / dt))
    times = np.arange(n) * dt
    curve = curve or Cmrt.zero(task.clip_s)
    disp = curve.displacement_m(times)
    disp_vel = curve.velocity_m_s(times)
    q_ref, qd_ref, qdd_ref = task.reference(times)

    d = mujoco.MjData(m)
    mujoco.mj_setState(m, d, settled_state(task, config), mujoco.mjtState.mjSTATE_INTEGRATION)
    mujoco.mj_forward(m, d)
    points = ch.foot_point_geoms
    settled_z = d.geom_xpos[list(points), 2].copy()
    controller = MomentumBalanceController(ch, config)

    rec = {
        k: np.full(s, np.nan)
        for k, s in {
            "qpos": (n, m.nq),
            "qvel": (n, m.nv),
            "com": (n, 2),
            "cop": n,
            "sc": n,
            "lo": n,
            "hi": n,
            "ffz": (n, 2),
            "lift": (n, 4),
            "cref": n,
            "ctrl": (n, m.nu),
        }.items()
    }
    force6 = np.zeros(6)
    fell, fall_time, reason, diverged, max_lift = False, None, None, False, 0.0
    ctrl = np.zeros(m.nu)
    last = n
    for k in range(n):
        t = times[k]
        mujoco.mj_step1(m, d)
        lo, hi = support_interval_x(d)
        center = 0.5 * (lo + hi)
        com_ref = center + disp[k]
        if k % config.control_every == 0:
            try:
                ctrl = controller.torques(d, q_ref[k], qd_ref[k], qdd_ref[k], com_ref, disp_vel[k], center)
            except np.linalg.LinAlgError:
                ctrl = np.full(m.nu, np.nan)
        if not np.all(np.isfinite(ctrl)):
            diverged, reason, last = True, "controller produced non-finite torques", k
            break
        d.ctrl[:] = ctrl
        d.xfrc_applied[ch.thorax_body, 0] = task.push_force_n(t)
        rec["qpos"][k], rec["qvel"][k] = d.qpos, d.qvel
        rec["com"][k] = d.subtree_com[1, [0, 2]]
        rec["sc"][k], rec["lo"][k], rec["hi"][k], rec["cref"][k] = center, lo, hi, com_ref
        rec["ctrl"][k] = ctrl
        lift = d.geom_xpos[list(points), 2] - settled_z
        rec["lift"][k] = lift
        mujoco.mj_step2(m, d)
        cop, fz_r, fz_l, other = _contact_summary(ch, m, d, force6)
        rec["cop"][k], rec["ffz"][k] = cop, (fz_r, fz_l)

        if d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number > 0 or not np.all(np.isfinite(d.qpos)):
            diverged, reason, last = True, "numerical blow-up (bad qacc)", k + 1
            break
        if fell:
            max_lift = max(max_lift, float(lift.max()))
        if other or rec["com"][k, 1] < FALL_COM_HEIGHT_M:
            if not fell:
                fell, fall_time = True, float(t)
                reason = "a body other than the feet touched the floor" if other else "CoM dropped too low"
            max_lift = max(max_lift, LIFT_STOP_M)
            last = k + 1
            break
        if not fell and lift.max() > LIFT_THRESHOLD_M:
            fell, fall_time, reason = True, float(t), "a support foot tipped (heel or toe lifted)"
            max_lift = float(lift.max())
        if fell and max_lift >= LIFT_STOP_M:
            last = k + 1
            break

    if diverged:
        fell = True
        fall_time = float(times[min(last, n - 1)]) if fall_time is None else fall_time
    cut = slice(0, last)
    return Trajectory(
        time_s=times[cut],
        qpos=rec["qpos"][cut],
        qvel=rec["qvel"][cut],
        com_m=rec["com"][cut],
        cop_x_m=rec["cop"][cut],
        support_center_x_m=rec["sc"][cut],
        support_lo_x_m=rec["lo"][cut],
        support_hi_x_m=rec["hi"][cut],
        foot_normal_force_n=rec["ffz"][cut],
        point_lift_m=rec["lift"][cut],
        cmrt_displacement_m=disp[cut],
        com_ref_x_m=rec["cref"][cut],
        ctrl_nm=rec["ctrl"][cut],
        fell=fell,
        fall_time_s=fall_time,
        fall_reason=reason,
        diverged=diverged,
        max_lift_m=max_lift,
        final_qpos=d.qpos.copy(),
    )
