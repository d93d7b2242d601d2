"""Where the momentum controller's reference CoM and CoP come from, every control step.

Two modes, chosen per task (``Task.reference_mode``, ``--reference``) and stored with every run:

``center`` (Macchietto et al. 2009, as ABC uses it): the reference CoM is the centre of the
support plus the CMRT, ``c_r = s + d(t)``, ``c_r' = d'(t)``, and the reference CoP is the
support centre, ``p_r = s``. Anticipation comes only from the CMRT.

``yu`` (Yu's thesis, eq. 3.2-3.5): the references react to the state instead.

* Reference CoM, eq. 3.2-3.3: the reference motion's own foot-to-CoM vector ``r_f(u)`` (forward
  kinematics of the reference pose at the same instant u) is placed on each actual foot and
  the two are blended by the feet's measured normal forces,
  ``c_r = sum_f w_f (x_f + r_f(u)) + d(t)``,  ``w_f = f_f / (f_r + f_l)``.
  ``x_f`` is the ankle (the foot body's origin). The CMRT ``d(t)`` still adds, so the two
  combine. ``c_r' = sum_f w_f r_f'(u) + d'(t)``: the feet are planted (their velocity is
  not part of the target) and the weights' rate is left out (it is the measurement's noise).
* Reference CoP, eq. 3.4 (Winter's inverted pendulum about the supporting ankle - the more
  loaded foot's): ``p_r = c - I / (W h) c''_des``, clipped to the support [heel, toe] of
  the feet, where ``c''_des = k_l (c_r - c) + d_l (c_r' - c')`` is the controller's own
  desired CoM acceleration, ``I`` the pitch inertia about the ankle of the body without its
  feet, ``W`` that body's weight and ``h`` the height of its CoM above the ankle. A point
  mass gives ``I / (W h) = h / g``: the linear inverted pendulum's ``p = c - (h / g) c''``.
  Eq. 3.5 is its frontal-plane twin; the character is planar.

With ``p_r`` from eq. 3.4 the angular-momentum objective asks for the CoP that the desired
linear momentum change needs, instead of pulling the CoP to the support centre against it.
The thesis then drives the CoP to ``p_r`` through a second PD loop (its eq. 3.19); we put
``p_r`` straight into ``Hdot_des = (p_r - c) x (Ldot_des - m g)`` as the center mode does
with ``s``, so the two modes differ only in their references (docs/controller.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from cmrt.body.character import GRAVITY_M_S2, Character

MIN_LOAD_N = 1.0  # below this total foot force the weights of eq. 3.3 are undefined: both feet count half


@dataclass(frozen=True)
class MotionCom:
    """The reference motion's horizontal CoM relative to each ankle, at every physics step (forward
    kinematics of the reference pose, eq. 3.2's r_f(u)), shape (steps, 2) for (right, left)."""

    foot_to_com_x_m: np.ndarray
    foot_to_com_vel_x_m_s: np.ndarray


def motion_com(ch: Character, q_ref: np.ndarray, qd_ref: np.ndarray) -> MotionCom:
    """r_f(u) and its rate from the reference pose and velocity ``(steps, nv)`` (the humanoid alone)."""
    m = ch.model
    d = mujoco.MjData(m)
    steps = q_ref.shape[0]
    rel = np.empty((steps, 2))
    rel_vel = np.empty((steps, 2))
    jac_com = np.empty((3, m.nv))
    jac_foot = np.empty((3, m.nv))
    last = None
    for k in range(steps):
        if last is not None and np.array_equal(q_ref[k], q_ref[last]) and np.array_equal(qd_ref[k], qd_ref[last]):
            rel[k], rel_vel[k] = rel[last], rel_vel[last]  # standing still: most of a clip
            continue
        d.qpos[:] = q_ref[k]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_jacSubtreeCom(m, d, jac_com, 1)
        com_vel_x = jac_com[0] @ qd_ref[k]
        for f, body in enumerate(ch.foot_bodies):
            mujoco.mj_jacBody(m, d, jac_foot, None, body)
            rel[k, f] = d.subtree_com[1, 0] - d.xpos[body, 0]
            rel_vel[k, f] = com_vel_x - jac_foot[0] @ qd_ref[k]
        last = k
    return MotionCom(rel, rel_vel)


class WinterPendulum:
    """Eq. 3.4's ``I / (W h)`` about an ankle, from MuJoCo's com-based inertias (the humanoid's bodies
    without its feet; a carried ball's mass is already in the forearms)."""

    def __init__(self, ch: Character):
        nb = ch.model.nbody
        self.bodies = np.array([b for b in range(1, nb) if b not in ch.foot_bodies])

    def ratio_s2(self, cinert: np.ndarray, com: np.ndarray, ankle_x: np.ndarray, ankle_z: np.ndarray) -> np.ndarray:
        """(n,) I / (W h) in s^2 for n simulations: ``cinert`` (n, nb, 10) about the whole CoM ``com`` (n, 3).

        The sums over bodies run body by body, element-wise over the batch: numpy's axis reductions round
        differently with the batch's size and layout, and a candidate's score must not depend on its batch."""
        n = cinert.shape[0]
        mass, mr_x, mr_z, inertia_c = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
        for b in self.bodies:
            ci = cinert[:, b]
            mass += ci[:, 9]
            mr_x += ci[:, 6]  # m (c_b - c): the body's CoM relative to the whole CoM
            mr_z += ci[:, 8]
            inertia_c += ci[:, 1]  # I_yy about the whole CoM
        body_x, body_z = com[:, 0] + mr_x / mass, com[:, 2] + mr_z / mass  # the body's CoM without its feet
        inertia_com = inertia_c - (mr_x * mr_x + mr_z * mr_z) / mass  # I_yy about its own CoM
        h = body_z - ankle_z
        dx = body_x - ankle_x
        inertia_ankle = inertia_com + mass * (dx * dx + h * h)
        return inertia_ankle / (mass * GRAVITY_M_S2 * h)


@dataclass(frozen=True)
class Targets:
    """The controller's references for n simulations at one control step (before the CMRT is added to the
    CoM): what ``MomentumBalanceController.torques`` takes as com_ref_x, com_ref_vel_x and cop_des_x."""

    com_x_m: np.ndarray
    com_vel_x_m_s: np.ndarray
    cop_x_m: np.ndarray


class YuReference:
    """Eq. 3.2-3.4 for a batch; ``targets`` is called every control step."""

    def __init__(self, ch: Character, k_l: float, d_l: float):
        self.ch = ch
        self.k_l, self.d_l = k_l, d_l
        self.feet = np.array(ch.foot_bodies)
        self.winter = WinterPendulum(ch)

    def targets(self, *, foot_force_n: np.ndarray, ankle_xz: np.ndarray, foot_to_com_x: np.ndarray,
                foot_to_com_vel_x: np.ndarray, disp_m: np.ndarray, disp_vel_m_s: np.ndarray, com: np.ndarray,
                com_vel_x: np.ndarray, cinert: np.ndarray, support_lo_x: np.ndarray,
                support_hi_x: np.ndarray, lean_x: np.ndarray | None = None) -> Targets:
        """References with the CMRT ``disp_m`` (n,) included (eq. 3.4 needs the CoM target it tracks).

        ``foot_force_n`` (n, 2) measured normal force per foot (right, left); ``ankle_xz`` (n, 2, 2) each
        ankle's (x, z); ``foot_to_com_x``/``_vel_x`` (n, 2) the reference motion's r_f(u) and rate; ``com``
        (n, 3) and ``com_vel_x`` (n,) the state; ``cinert`` (n, nb, 10); support bounds (n,)."""
        # two-term sums written out: row-wise arithmetic whatever the batch (see WinterPendulum.ratio_s2)
        total = (foot_force_n[:, 0] + foot_force_n[:, 1])[:, None]
        w = np.where(total > MIN_LOAD_N, foot_force_n / np.maximum(total, MIN_LOAD_N), 0.5)
        placed = ankle_xz[:, :, 0] + foot_to_com_x
        com_ref = w[:, 0] * placed[:, 0] + w[:, 1] * placed[:, 1] + disp_m
        com_ref_vel = w[:, 0] * foot_to_com_vel_x[:, 0] + w[:, 1] * foot_to_com_vel_x[:, 1] + disp_vel_m_s
        acc_des = self.k_l * (com_ref - com[:, 0]) + self.d_l * (com_ref_vel - com_vel_x)
        ankle = np.take_along_axis(ankle_xz, np.argmax(foot_force_n, axis=1)[:, None, None], axis=1)[:, 0]
        ratio = self.winter.ratio_s2(cinert, com, ankle[:, 0], ankle[:, 1])
        # Winter's CoP under the CoM; on a tilted support under its ground point along gravity (``lean_x``: the
        # CoM's offset from it, cmrt.body.surface.Support.lean_x)
        under = com[:, 0] if lean_x is None else com[:, 0] - lean_x
        cop = np.clip(under - ratio * acc_des, support_lo_x, support_hi_x)
        return Targets(com_ref, com_ref_vel, cop)
