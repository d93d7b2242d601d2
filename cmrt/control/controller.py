"""The reactive momentum balance controller (ABC section 3; Macchietto et al. 2009).

Per control step it plans joint accelerations qdd* by one equality-constrained least
squares (a KKT solve):

    min  b_l |Ldot_x,des - (A_x qdd + a_x)|^2 + b_h |Hdot_des - (A_h qdd + a_h)|^2
         + b_t |W (qdd_des - qdd)|^2 + eps |qdd|^2
    s.t. J_s qdd + Jdot_s qd = 0            (support feet do not accelerate)

with  Ldot_x,des = k_l m (c_r - c) + d_l (m cdot_r - L_x),   c_r = s + d(t)  (CMRT),
      Hdot_des   = [(p_des - c) x (Ldot_des - m g)]_y,       p_des = s (support centre),
      qdd_des    = k_t (q_r - q) + d_t (qd_r - qd) + qdd_r.

Torques: tau = [M qdd* + h - J_c^T f*] on the actuated rows, clipped to the motor
limits, where f* is the ground force the *plan* implies: the minimum-norm solution of
the three root rows of M qdd* + h = J_c^T f over the heel and toe points of both feet,
with no unilateral or friction limits. Why this choice (see docs/controller.md):

* A QP that keeps contact forces unilateral inside the plan hides the failure the
  product is about (the controller silently stops tracking instead of tipping).
* Torques from the *measured* contact forces of the previous step are one step late
  and tip two-foot standing in MuJoCo within a fraction of a second.
* The plan-implied force is delay free. When the plan needs a CoP outside the feet,
  the torques ask the ground for a pull it cannot give, the foot tips, and balance
  is lost physically - exactly what a CMRT must prevent.

The linear algebra (``plan_accelerations``, ``implied_torques``) works on arrays with
any leading batch axes, so a population of simulations can later be controlled in
lockstep without a rewrite.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from cmrt.character import FOOT_POINT_RADIUS_M, Character
from cmrt.control.momentum import KinematicsScratch, centroidal_momentum_matrix, foot_jacobian

GRAVITY_M_S2 = 9.81


@dataclass(frozen=True)
class ControllerConfig:
    """Gains and weights. Values and why: docs/controller.md."""

    k_l: float = 10.0  # 1/s^2, CoM stiffness of the linear-momentum objective
    d_l: float = 2.0 * math.sqrt(10.0)  # 1/s, its damping (critical for k_l)
    k_t: float = 100.0  # 1/s^2, joint tracking stiffness
    d_t: float = 20.0  # 1/s, joint tracking damping (critical for k_t)
    beta_l: float = 0.01  # weight of the linear-momentum objective
    beta_h: float = 0.01  # weight of the angular-momentum objective
    beta_t: float = 1.0  # weight of the tracking objective
    weight_upper: float = 1.0  # W for lumbar, neck and arms
    weight_leg: float = 0.2  # W for hips, knees, ankles: legs give way to balance
    weight_root_pitch: float = 0.2  # W for the trunk's absolute pitch
    regularization: float = 1e-6  # eps on |qdd|^2, keeps the KKT matrix regular
    control_every: int = 1  # physics steps per control step (1 -> 500 Hz at 2 ms)

    def tracking_weights(self, ch: Character) -> np.ndarray:
        w = np.full(ch.nv, self.weight_upper)
        w[ch.root_dofs[0]] = w[ch.root_dofs[1]] = 0.0  # root translation is not tracked
        w[ch.root_dofs[2]] = self.weight_root_pitch
        for i, name in enumerate(ch.dof_names):
            if name.split("_")[0] in ("hip", "knee", "ankle"):
                w[i] = self.weight_leg
        return w


def plan_accelerations(Q: np.ndarray, g: np.ndarray, Js: np.ndarray, rhs_s: np.ndarray) -> np.ndarray:
    """Solve min 1/2 qdd'Q qdd - g'qdd  s.t. Js qdd = rhs_s; batched over leading axes."""
    nv, nc = Q.shape[-1], Js.shape[-2]
    K = np.zeros(Q.shape[:-2] + (nv + nc, nv + nc))
    K[..., :nv, :nv] = Q
    K[..., :nv, nv:] = np.swapaxes(Js, -1, -2)
    K[..., nv:, :nv] = Js
    rhs = np.concatenate([g, rhs_s], axis=-1)
    return np.linalg.solve(K, rhs[..., None])[..., :nv, 0]


def implied_torques(
    M: np.ndarray, h: np.ndarray, qdd: np.ndarray, Jc: np.ndarray, root: slice
) -> tuple[np.ndarray, np.ndarray]:
    """Generalised forces M qdd + h - Jc' f with f the min-norm force balancing the root rows."""
    need = np.einsum("...ij,...j->...i", M, qdd) + h
    B = np.swapaxes(Jc, -1, -2)[..., root, :]  # (3, n_force)
    f = np.einsum("...ji,...j->...i", B, np.linalg.solve(B @ np.swapaxes(B, -1, -2), need[..., root]))
    return need - np.einsum("...ji,...j->...i", Jc, f), f


class MomentumBalanceController:
    """Stateless apart from scratch buffers; call :meth:`torques` after ``mj_step1``."""

    def __init__(self, ch: Character, config: ControllerConfig = ControllerConfig()):
        self.ch = ch
        self.config = config
        self.model = ch.model
        self.w2 = config.tracking_weights(ch) ** 2
        self.scratch = KinematicsScratch(ch.model, ch.foot_bodies)
        self.actuated = np.array(ch.actuated_dofs)
        self.limits = ch.torque_limit_nm
        self.mass = ch.mass_kg
        self.root = slice(0, 3)
        self.M = np.empty((ch.nv, ch.nv))
        self._jacp = np.empty((3, ch.nv))
        # Contact points: bottoms of the heel and toe spheres, in their geom frames.
        self.points = [g for pair in ch.foot_points for g in pair]
        self.last_qdd = np.zeros(ch.nv)
        self.last_force = np.zeros(2 * len(self.points))

    def torques(
        self,
        data: mujoco.MjData,
        q_ref: np.ndarray,
        qd_ref: np.ndarray,
        qdd_ref: np.ndarray,
        com_ref_x: float,
        com_ref_vel_x: float,
        cop_des_x: float,
    ) -> np.ndarray:
        m, d, cfg = self.model, data, self.config
        qpos, qvel = d.qpos.copy(), d.qvel.copy()
        A = centroidal_momentum_matrix(m, d)
        Js = np.concatenate([foot_jacobian(m, d, b) for b in self.ch.foot_bodies])
        a, jsdot_qd = self.scratch.biases(qpos, qvel)
        L = A @ qvel
        com = d.subtree_com[1]

        ldot_x = cfg.k_l * self.mass * (com_ref_x - com[0]) + cfg.d_l * (self.mass * com_ref_vel_x - L[0])
        force_x, force_z = ldot_x, self.mass * GRAVITY_M_S2  # desired ground force (Ldot_z,des = 0)
        hdot = -com[2] * force_x - (cop_des_x - com[0]) * force_z
        qdd_des = cfg.k_t * (q_ref - qpos) + cfg.d_t * (qd_ref - qvel) + qdd_ref

        Ax, Ah = A[0], A[2]
        Q = cfg.beta_l * np.outer(Ax, Ax) + cfg.beta_h * np.outer(Ah, Ah)
        Q += np.diag(cfg.beta_t * self.w2 + cfg.regularization)
        g = cfg.beta_l * Ax * (ldot_x - a[0]) + cfg.beta_h * Ah * (hdot - a[2]) + cfg.beta_t * self.w2 * qdd_des
        qdd = plan_accelerations(Q, g, Js, -jsdot_qd)

        mujoco.mj_fullM(m, d, self.M)
        h = d.qfrc_bias - d.qfrc_passive
        Jc = np.empty((2 * len(self.points), m.nv))
        for k, gid in enumerate(self.points):
            point = d.geom_xpos[gid] - np.array([0.0, 0.0, FOOT_POINT_RADIUS_M])
            mujoco.mj_jac(m, d, self._jacp, None, point, m.geom_bodyid[gid])
            Jc[2 * k] = self._jacp[0]
            Jc[2 * k + 1] = self._jacp[2]
        tau, f = implied_torques(self.M, h, qdd, Jc, self.root)
        self.last_qdd, self.last_force = qdd, f
        return np.clip(tau[self.actuated], -self.limits, self.limits)
