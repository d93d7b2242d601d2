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
with no unilateral or friction limits. Why this choice (docs/controller.md):

* A QP that keeps contact forces unilateral inside the plan hides the failure the
  product is about (the controller silently stops tracking instead of tipping).
* Torques from the *measured* contact forces of the previous step are one step late
  and tip two-foot standing in MuJoCo within a fraction of a second.
* The plan-implied force is delay free. When the plan needs a CoP outside the feet,
  the torques ask the ground for a pull it cannot give, the foot tips, and balance
  is lost physically - exactly what a CMRT must prevent.

Everything is vectorised over a leading axis of n simulations (one CMA-ES generation
stepped in lockstep with ``mujoco.batch.Batch``); a single clip is the case n = 1, so
there is one implementation and batched and serial objectives agree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cmrt.character import FOOT_POINT_RADIUS_M, Character
from cmrt.control.planar import PlanarKinematics

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
    control_every: int = 4  # physics steps per control step: 125 Hz at the 2 ms step (ABC: 60-120 Hz)

    def tracking_weights(self, ch: Character) -> np.ndarray:
        w = np.full(ch.nv, self.weight_upper)
        w[ch.root_dofs[0]] = w[ch.root_dofs[1]] = 0.0  # root translation is not tracked
        w[ch.root_dofs[2]] = self.weight_root_pitch
        for i, name in enumerate(ch.dof_names):
            if name.split("_")[0] in ("hip", "knee", "ankle"):
                w[i] = self.weight_leg
        return w


def plan_accelerations(Q: np.ndarray, g: np.ndarray, Js: np.ndarray, rhs_s: np.ndarray) -> np.ndarray:
    """Solve min 1/2 qdd'Q qdd - g'qdd  s.t. Js qdd = rhs_s; batched over the leading axis."""
    nv, nc = Q.shape[-1], Js.shape[-2]
    K = np.zeros(Q.shape[:-2] + (nv + nc, nv + nc))
    K[..., :nv, :nv] = Q
    K[..., :nv, nv:] = np.swapaxes(Js, -1, -2)
    K[..., nv:, :nv] = Js
    rhs = np.concatenate([g, rhs_s], axis=-1)
    return np.linalg.solve(K, rhs[..., None])[..., :nv, 0]


def implied_torques(M: np.ndarray, h: np.ndarray, qdd: np.ndarray, Jc: np.ndarray) -> np.ndarray:
    """Generalised forces M qdd + h - Jc' f, f the min-norm force balancing the 3 root rows."""
    need = (M @ qdd[..., None])[..., 0] + h
    B = np.swapaxes(Jc[..., :3], -1, -2)  # (n, 3, n_force): root rows of Jc'
    lam = np.linalg.solve(B @ np.swapaxes(B, -1, -2), need[..., :3, None])
    f = (np.swapaxes(B, -1, -2) @ lam)[..., 0]
    return need - (np.swapaxes(Jc, -1, -2) @ f[..., None])[..., 0]


class MomentumBalanceController:
    """Computes motor torques for n simulations from their bound MuJoCo fields."""

    def __init__(self, ch: Character, config: ControllerConfig = ControllerConfig()):
        self.ch = ch
        self.config = config
        self.kin = PlanarKinematics(ch.model)  # the humanoid alone: props come after it in any model
        self.nv, self.nbody, self.nM = ch.model.nv, ch.model.nbody, ch.model.nM
        self.w2 = config.tracking_weights(ch) ** 2
        self.diag = config.beta_t * self.w2 + config.regularization
        self.actuated = np.array(ch.actuated_dofs)
        self.limits = ch.torque_limit_nm
        self.mass = ch.mass_kg
        self.points = np.array(ch.foot_point_geoms)
        self.point_bodies = ch.model.geom_bodyid[self.points]
        self.point_offset = np.array([0.0, 0.0, FOOT_POINT_RADIUS_M])  # sphere centre -> bottom
        self.feet = np.array(ch.foot_bodies)

    def torques(self, f: dict[str, np.ndarray], q_ref, qd_ref, qdd_ref, com_ref_x, com_ref_vel_x, cop_des_x):
        """Torques (n, nu). ``f`` holds (n, ...) arrays of the MuJoCo fields at the current state:
        qpos, qvel, cdof, cdof_dot, cvel, cinert, M, qfrc_bias, qfrc_passive, subtree_com, xpos,
        geom_xpos. References (nv,) are shared; CoM/CoP targets are (n,)."""
        cfg, kin = self.config, self.kin
        nv, nb = self.nv, self.nbody  # a task model may append props: use the humanoid's slices
        qpos, qvel = f["qpos"][:, :nv], f["qvel"][:, :nv]
        cdof, cdof_dot, cvel = f["cdof"][:, :nv], f["cdof_dot"][:, :nv], f["cvel"][:, :nb]
        com = f["subtree_com"][:, 1]
        A, a = kin.centroidal(cdof, cdof_dot, cvel, f["cinert"][:, :nb], qvel)
        n = qvel.shape[0]
        Js, jsdot = kin.frame_jacobians_and_biases(cdof, cdof_dot, cvel, qvel, f["xpos"][:, self.feet], com,
                                                   self.feet)
        Js, jsdot = Js.reshape(n, -1, nv), jsdot.reshape(n, -1)
        L_x = (A[:, 0] * qvel).sum(axis=1)

        ldot_x = cfg.k_l * self.mass * (com_ref_x - com[:, 0]) + cfg.d_l * (self.mass * com_ref_vel_x - L_x)
        # desired ground force (Ldot_z,des = 0) placed at the desired CoP
        hdot = -com[:, 2] * ldot_x - (cop_des_x - com[:, 0]) * (self.mass * GRAVITY_M_S2)
        qdd_des = cfg.k_t * (q_ref - qpos) + cfg.d_t * (qd_ref - qvel) + qdd_ref

        Ax, Ah = A[:, 0], A[:, 2]
        Q = cfg.beta_l * Ax[:, :, None] * Ax[:, None, :] + cfg.beta_h * Ah[:, :, None] * Ah[:, None, :]
        Q[:, np.arange(nv), np.arange(nv)] += self.diag
        g = (cfg.beta_l * (ldot_x - a[:, 0]))[:, None] * Ax + (cfg.beta_h * (hdot - a[:, 2]))[:, None] * Ah
        g += cfg.beta_t * self.w2 * qdd_des
        qdd = plan_accelerations(Q, g, Js, -jsdot)

        points = f["geom_xpos"][:, self.points] - self.point_offset  # (n, 4, 3)
        Jc = kin.point_jacobians(cdof, points, com, self.point_bodies).reshape(n, -1, nv)
        h = f["qfrc_bias"][:, :nv] - f["qfrc_passive"][:, :nv]
        tau = implied_torques(kin.dense_mass_matrix(f["M"][:, : self.nM]), h, qdd, Jc)
        return np.clip(tau[:, self.actuated], -self.limits, self.limits)
