"""The momentum balance controller in three dimensions (Macchietto et al. 2009), over a body's description.

The planar kernel (``cmrt.control.kernel``) plans one net ground wrench; a 3D foot rests on four points, and the
ground can only push each one inside its own friction cone. So this controller plans what TSID calls the contact
forces themselves: its unknowns are the joint accelerations qdd (nv) and a force per loaded contact point (3 each),
and it solves, every control step, the small QP

    min  b_l |A_L qdd + a_L - Ldot_des|^2 + b_h |A_H qdd + a_H - Hdot_des|^2 + b_t |W (qdd_des - qdd)|^2
         + eps (|qdd|^2 + |f|^2)
    s.t. M_base qdd + h_base = J_base^T f           (the floating base moves only as the forces say: 6 rows)
         J_foot qdd + Jdot_foot qd = -k_s J_foot qd  (a supporting foot stays where it is: 6 rows per foot)
         f_z >= f_min,  |f_x| + |f_y| <= mu f_z      (a friction pyramid per point: MuJoCo's, below)
         |M_act qdd + h_act - J_act^T f| <= tau_max  (the motors' limits, as in the planar plan)
         qdd >= -k_j (q - lo) - d_j qd, qdd <= -k_j (q - hi) - d_j qd  (each joint's stops, less a margin)

with the planar controller's objectives written in 3D: Ldot_des = k_l m (c_r - c) + d_l (m cdot_r - L) on the CoM
and its velocity sensed ``feedback_delay_s`` ago (a person's reaction), and Hdot_des = (p_r - c) x (Ldot_des + m g)
- the angular momentum rate that puts the CoP at its reference p_r, the support's centre (the planar rule
``hdot = -c_z ldot_x - (p_x - c_x) m g`` is its y row). The CoP is inside the feet's polygon by construction: every
point's force is a cone's. Gains and weights are the planar ``ControllerConfig``'s (docs/controller.md).

The friction pyramid is the one MuJoCo's contacts have, scaled by ``friction_coef`` (0.8 of the floor's 1.0, the
planar plan's margin): MuJoCo's default (pyramidal) cone is spanned by the edges n +- mu t1 and n +- mu t2, so its
tangential force obeys |f_t1| + |f_t2| <= mu f_n - a diamond, whose tangents on the floor are the world's y and
-x. A box |f_x|, |f_y| <= mu f_z (this controller's first) reaches 1.6 mu f_z at its corners: where a plan asked
for a turn of the feet (a one-arm punch's return), its points were given forces MuJoCo cannot hold, and the feet
twisted and the CoP ran 63 mm off the plan (measured; tests/control/test_spatial.py checks the cone itself).

The torques follow from the plan by inverse dynamics (the actuated rows of M qdd + h - J^T f), so the plan is what
the motors are asked for; MuJoCo's own M, bias forces, Jacobians and their rates are used throughout, and the
centroidal momentum's bias is ``kernel.centroidal_spatial``'s, the rows the planar kernel also uses.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import daqp
import mujoco
import numpy as np

from cmrt.body.character import GRAVITY_M_S2, Character
from cmrt.control import kernel
from cmrt.control.controller import ControllerConfig
from cmrt.control.planar import PlanarKinematics
from cmrt.errors import CmrtError

N_BASE = 6  # a free root's dofs
EQUALITY = 5  # daqp's sense for an equality row


@dataclass(frozen=True)
class SpatialPlan:
    """What one control step planned: the actuator torques (N m), each contact point's force (N, world frame; zero
    where the point is not loaded) and the CoP those forces put on the floor (m, x and y)."""

    torque_nm: np.ndarray
    point_force_n: np.ndarray
    cop_xy_m: np.ndarray


@dataclass(frozen=True)
class SpatialTargets:
    """What a motion asks of a control step beyond holding still: the CoM's horizontal reference and its rate (a
    CMRT's displacement included), the CoP's reference, and a foot off the floor with the path of its frame's origin
    (world, m; its orientation is held level). None: the standing defaults."""

    com_xy_m: np.ndarray | None = None
    com_vel_xy_m_s: np.ndarray | None = None
    cop_xy_m: np.ndarray | None = None
    q_ref: np.ndarray | None = None  # (nq): the pose to track now (None: the one the controller was made with)
    qd_ref: np.ndarray | None = None  # (nv): its rate and acceleration (None: still), tracked as the planar
    qdd_ref: np.ndarray | None = None  # controller tracks them (k_t (q_r - q) + d_t (qd_r - qd) + qdd_r)
    swing_foot: int = -1  # 0 right, 1 left; -1 none
    swing_pos_m: np.ndarray | None = None
    swing_vel_m_s: np.ndarray | None = None


class SpatialController:
    """The 3D momentum controller of one simulation: ``plan`` once per control step on a forward-computed MjData.
    ``q_ref`` (nq) is the pose it holds, kept ``stop_margin_rad`` inside every joint's stops. ``model``: the clip's
    own (default the body's): a task's prop comes after the humanoid in it (``cmrt.body.props``), so the humanoid's
    bodies and dofs lead and the plan is over them - a prop is a separate tree, its dofs no part of the humanoid's
    inertia or Jacobians - and what the prop does to the hands reaches the plan as ``plan``'s ``load_gen`` (a
    generalized force) or ``held_mass`` (a mass the hands carry)."""

    def __init__(self, ch: Character, q_ref: np.ndarray, config: ControllerConfig = ControllerConfig(),
                 control_step_s: float | None = None, model: mujoco.MjModel | None = None):
        m = ch.model
        self.model = m if model is None else model
        self.nv = m.nv  # the humanoid's dofs: the plan's qdd
        if m.nv - len(ch.actuated_dofs) != N_BASE:
            raise CmrtError(f"the 3D controller needs a free root: body {ch.body!r} has {m.nv - len(ch.actuated_dofs)}"
                            " unactuated dofs")
        self.ch, self.config = ch, config
        self.act_dofs = np.asarray(ch.actuated_dofs)
        self.act_qpos = m.jnt_qposadr[m.dof_jntid[self.act_dofs]]
        lo, hi = ch.joint_range_rad()
        self.stops = (lo + config.stop_margin_rad, hi - config.stop_margin_rad)  # the plan stays inside these
        self.q_ref = np.asarray(q_ref, float).copy()  # ... and so does the reference (a standing knee's 0 is a stop)
        self.q_ref[self.act_qpos] = np.clip(self.q_ref[self.act_qpos], *self.stops)
        self.gear = m.actuator_gear[:, 0]
        self.points = ch.foot_point_geoms
        self.chain = PlanarKinematics(m).chain.astype(bool)
        # the planar floor per heel or toe point, shared by the points across that end of a 3D foot: the same
        # force per length of foot, so the same share of the foot stays open to the CoP
        self.point_floor_n = config.min_point_force_n * 4 / len(self.points)
        self.mass_kg = float(self.model.body_subtreemass[1])  # with what the forearms carry (a handed-over ball)
        step_s = control_step_s if control_step_s is not None else m.opt.timestep * config.control_every
        self.delay_steps = int(round(config.feedback_delay_s / step_s))
        self.history: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=self.delay_steps + 1)
        self.com_ref_m: np.ndarray | None = None  # the CoM held: where it was at the first control step
        self.cop_ref_m: np.ndarray | None = None  # the CoP asked for: the feet's centre at the first control step
        self.infeasible = False  # the last plan found none within the stops and limits (clipped after the solve)
        self._constant_parts()

    def plan(self, d: mujoco.MjData, loaded: np.ndarray, targets: SpatialTargets = SpatialTargets(),
             load_gen: np.ndarray | None = None,
             held_mass: tuple[float, np.ndarray, tuple[int, ...]] | None = None) -> SpatialPlan:
        """Plan this control step from ``d`` (after mj_forward) with ``loaded`` (n points,) the points touching
        the floor; raises CmrtError where the QP has no solution (the feet cannot carry the body). ``load_gen``:
        the generalized force (nv; N, N m) of what the character holds (a caught ball's pull on the hands), known
        to the plan as the planar kernel knows a held load: the floating base moves under the ground's forces and
        it, and the torques take it out. ``held_mass``: a mass the hands hold (kg), where (world, m) and the bodies
        holding it equally - a gripped ball moving with them, its weight and its inertia in the plan's dynamics."""
        m, c = self.model, self.config
        nv, n_pts = self.nv, len(self.points)
        self.mass_kg = float(m.body_subtreemass[1])
        com = d.subtree_com[1].copy()
        A, a = self._momentum(d)
        self.history.append((com, A[:3] @ d.qvel[:nv] / self.mass_kg))
        if self.com_ref_m is None:
            self.com_ref_m = com.copy()
            self.cop_ref_m = d.geom_xpos[list(self.points), :2].mean(axis=0)
        com_seen, vel_seen = self.history[0]  # the state ``feedback_delay_s`` ago (the oldest kept)
        com_ref, vel_ref = self.com_ref_m.copy(), np.zeros(3)
        if targets.com_xy_m is not None:
            com_ref[:2] = targets.com_xy_m
        if targets.com_vel_xy_m_s is not None:
            vel_ref[:2] = targets.com_vel_xy_m_s
        ldot = c.k_l * self.mass_kg * (com_ref - com_seen) + c.d_l * self.mass_kg * (vel_ref - vel_seen)
        ldot[2] = 0.0  # horizontal, as the planar rule: the CoM's height follows the pose (a bend lowers it)
        force = ldot + np.array([0.0, 0.0, self.mass_kg * GRAVITY_M_S2])
        cop_ref = self.cop_ref_m if targets.cop_xy_m is None else targets.cop_xy_m
        p_ref = np.array([cop_ref[0], cop_ref[1], 0.0])
        if targets.swing_foot >= 0:
            loaded = loaded.copy()
            loaded[self._foot_point_index[targets.swing_foot]] = False
        r = p_ref - com
        hdot = np.array([r[1] * force[2] - r[2] * force[1], r[2] * force[0] - r[0] * force[2],
                         r[0] * force[1] - r[1] * force[0]])  # r x force (np.cross: 40 us a call)
        Jp = self._point_jacobians(d)
        H_qp, f_qp = self._objective(d, A, a, ldot, hdot, n_pts, targets)
        if targets.swing_foot >= 0:
            self._swing_objective(d, targets, H_qp, f_qp)
        M = np.zeros((m.nv, m.nv))  # the joint-space inertia, once a control step: the rows and the torques use it
        mujoco.mj_fullM(m, d, M)
        M = M[:nv, :nv]
        bias = d.qfrc_bias[:nv] - (load_gen if load_gen is not None else 0.0)
        if held_mass is not None:
            M, bias = self._holding(d, M, bias, held_mass)
        rows, lo, hi, sense = self._constraints(d, M, Jp, loaded, bias)
        x, _, flag, _ = daqp.solve(H_qp, f_qp, rows, hi, lo, sense)
        self.infeasible = flag < 1
        if self.infeasible:  # no plan within the stops and the motors' limits (a fall): the plan without those
            n_limits = 2 * len(self.act_dofs)  # rows (the last), its torques clipped after the solve
            x, _, flag, _ = daqp.solve(H_qp, f_qp, rows[:-n_limits], hi[:-n_limits], lo[:-n_limits],
                                       sense[:-n_limits])
            if flag < 1:
                raise CmrtError(f"the 3D balance QP has no solution (daqp exit {flag})")
        qdd, forces = x[:nv], x[nv:].reshape(n_pts, 3)
        generalized = M @ qdd + bias - Jp.T @ x[nv:]
        torque = np.clip(generalized[self.act_dofs], -self.ch.torque_limit_nm, self.ch.torque_limit_nm)
        fz = forces[:, 2].sum()
        xy = d.geom_xpos[list(self.points), :2]
        cop = (forces[:, 2:3] * xy).sum(axis=0) / fz if fz > 1e-9 else np.full(2, np.nan)
        return SpatialPlan(torque / self.gear, forces, cop)

    def _momentum(self, d: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """The centroidal momentum matrix (6, nv) - MuJoCo's own - and its bias, A qdd + a being the rate."""
        m = self.model
        A = np.empty((6, m.nv))
        mujoco.mj_jacSubtreeCom(m, d, A[:3], 1)
        A[:3] *= self.mass_kg
        mujoco.mj_angmomMat(m, d, A[3:], 1)
        _, a = kernel.centroidal_spatial(d.cdof, d.cdof_dot, d.cvel, d.cinert, d.qvel, self.chain)
        return A[:, :self.nv], a

    def _point_jacobians(self, d: mujoco.MjData) -> np.ndarray:
        """The contact points' translational Jacobians stacked (3 n, nv), at each sphere's lowest point."""
        m, jacp = self.model, self._jacp
        lowest = d.geom_xpos[self._point_ids] - self._point_drop
        for p, body in enumerate(self._point_bodies):
            mujoco.mj_jac(m, d, jacp[p], None, lowest[p], body)
        return jacp[:, :, :self.nv].reshape(-1, self.nv)

    def _objective(self, d: mujoco.MjData, A: np.ndarray, a: np.ndarray, ldot: np.ndarray, hdot: np.ndarray,
                   n_pts: int, targets: SpatialTargets) -> tuple[np.ndarray, np.ndarray]:
        """The QP's cost (H, f) over x = [qdd, f]: momentum rates, joint tracking, a small regularization. The
        tracking feeds the reference's rate and acceleration forward, as the planar kernel's: without them a
        moving reference is followed d_t / k_t = 0.2 s late (a leg lift's swing leg was, measured)."""
        c, nv = self.config, self.ch.model.nv
        n = nv + 3 * n_pts
        H = np.zeros((n, n))
        f = np.zeros(n)
        H[:nv, :nv] += c.beta_l * A[:2].T @ A[:2] + c.beta_h * A[3:].T @ A[3:]
        f[:nv] -= c.beta_l * A[:2].T @ (ldot[:2] - a[:2]) + c.beta_h * A[3:].T @ (hdot - a[3:])
        q = d.qpos[self.act_qpos]
        qd = d.qvel[self.act_dofs]
        ref = self.q_ref if targets.q_ref is None else targets.q_ref
        qdd_des = c.k_t * (np.clip(ref[self.act_qpos], *self.stops) - q) - c.d_t * qd
        if targets.qd_ref is not None:
            qdd_des += c.d_t * targets.qd_ref[self.act_dofs]
        if targets.qdd_ref is not None:
            qdd_des += targets.qdd_ref[self.act_dofs]
        H[self.act_dofs, self.act_dofs] += c.beta_t
        f[self.act_dofs] -= c.beta_t * qdd_des
        H[np.arange(n), np.arange(n)] += c.regularization
        return 2.0 * H, 2.0 * f

    def _swing_objective(self, d: mujoco.MjData, targets: SpatialTargets, H: np.ndarray, f: np.ndarray) -> None:
        """A lifted foot's frame toward its path (the planar swing objective's weight and gains), level, in place
        into the QP's cost (H, f as ``_objective`` returns them)."""
        c, nv = self.config, self.nv
        body = self.ch.foot_bodies[targets.swing_foot]
        jac, jdot = self._frame_jacobians(d, body)
        vel = jac @ d.qvel[:nv]
        local, level = np.zeros(3), np.zeros(3)  # the rotation from the foot's frame to level (axis x angle)
        mujoco.mju_subQuat(local, np.array([1.0, 0.0, 0.0, 0.0]), d.xquat[body])  # in the foot's frame ...
        mujoco.mju_rotVecQuat(level, local, d.xquat[body])  # ... and in the world's, as the Jacobian's rows
        want = np.concatenate([
            c.swing_k * (targets.swing_pos_m - d.xpos[body]) + c.swing_d * (targets.swing_vel_m_s - vel[:3]),
            c.swing_k * level - c.swing_d * vel[3:]]) - jdot @ d.qvel[:nv]
        H[:nv, :nv] += 2.0 * c.swing_weight * jac.T @ jac
        f[:nv] -= 2.0 * c.swing_weight * jac.T @ want

    def _holding(self, d: mujoco.MjData, M: np.ndarray, bias: np.ndarray,
                 held_mass: tuple[float, np.ndarray, tuple[int, ...]]) -> tuple[np.ndarray, np.ndarray]:
        """The body's dynamics with a point mass carried by the hands (M qdd + bias): the mass accelerates with
        its point on the bodies holding it (the mean of their Jacobians there, J, and rates), so its force on them,
        m (g - J qdd - Jdot qd), adds m J^T J to the inertia and m J^T (Jdot qd - g) to the bias. Planning with a
        held ball's inertia, not only last step's pull: the pull alone, measured one step late, left the arms'
        rotation about their own axes - whose inertia the 7 kg ball outweighs fifty times - swinging 0.4 rad."""
        mass, point, bodies = held_mass
        m = self.model
        jac, jdot = np.zeros((3, self.nv)), np.zeros((3, self.nv))
        one, rate = np.empty((3, m.nv)), np.empty((3, m.nv))
        for body in bodies:
            mujoco.mj_jac(m, d, one, None, np.asarray(point, float), int(body))
            mujoco.mj_jacDot(m, d, rate, None, np.asarray(point, float), int(body))
            jac += one[:, :self.nv] / len(bodies)
            jdot += rate[:, :self.nv] / len(bodies)
        gravity = np.array([0.0, 0.0, -GRAVITY_M_S2])
        return M + mass * jac.T @ jac, bias + mass * jac.T @ (jdot @ d.qvel[:self.nv] - gravity)

    def _frame_jacobians(self, d: mujoco.MjData, body: int) -> tuple[np.ndarray, np.ndarray]:
        """A body frame's [linear, angular] Jacobian (6, nv) and its rate, MuJoCo's (``mj_jacBody``,
        ``mj_jacDot``)."""
        m = self.model
        jac, jdot = np.empty((6, m.nv)), np.empty((6, m.nv))
        mujoco.mj_jacBody(m, d, jac[:3], jac[3:], body)
        mujoco.mj_jacDot(m, d, jdot[:3], jdot[3:], d.xpos[body], body)
        return jac[:, :self.nv], jdot[:, :self.nv]

    def _constraints(self, d: mujoco.MjData, M: np.ndarray, Jp: np.ndarray, loaded: np.ndarray, bias: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The QP's rows (A, lo, hi, sense), in this order: base dynamics and supporting feet (equalities), each
        point's floor and friction pyramid (a point off the floor carries nothing), each joint's stops, the motors'
        limits. ``bias``: the generalized forces the plan does not choose (MuJoCo's bias forces less a held
        load's). Written as whole blocks (the rows that never change made once, ``_constant_parts``): row by row in
        Python this was a third of a 3D clip's time."""
        c, nv, act = self.config, self.nv, self.act_dofs
        ground, stops = self._ground_rows, self._stop_rows
        feet = [foot for foot, pair in enumerate(self.ch.foot_points) if loaded[self._foot_point_index[foot]].any()]
        n_eq = N_BASE * (1 + len(feet))
        rows = np.empty((n_eq + len(ground) + len(stops) + len(act), ground.shape[1]))
        lo, hi = np.empty(rows.shape[0]), np.empty(rows.shape[0])
        rows[:N_BASE, :nv], rows[:N_BASE, nv:] = M[:N_BASE], -Jp[:, :N_BASE].T  # M_base qdd - J_base^T f = -h_base
        lo[:N_BASE] = hi[:N_BASE] = -bias[:N_BASE]
        qvel = d.qvel[:nv]
        for k, foot in enumerate(feet):
            jac, jdot = self._frame_jacobians(d, self.ch.foot_bodies[foot])
            at = slice(N_BASE * (1 + k), N_BASE * (2 + k))
            rows[at, :nv], rows[at, nv:] = jac, 0.0
            lo[at] = hi[at] = -jdot @ qvel - c.support_damping * (jac @ qvel)
        at = n_eq + len(ground)
        rows[n_eq:at] = ground
        lo[n_eq:at], hi[n_eq:at] = self._ground_lo, self._ground_hi
        lo[n_eq:at:5] = np.where(loaded, self.point_floor_n, 0.0)  # each point's floor: its first row of five
        hi[n_eq:at:5] = np.where(loaded, np.inf, 0.0)
        q, qd = d.qpos[self.act_qpos], d.qvel[act]
        low = -c.stop_k * (q - self.stops[0]) - c.stop_d * qd  # approach a stop no faster than a critically
        high = -c.stop_k * (q - self.stops[1]) - c.stop_d * qd  # damped spring
        rows[at:at + len(stops)] = stops
        lo[at:at + len(stops)] = np.where(np.isfinite(low), low, -np.inf)
        hi[at:at + len(stops)] = np.where(np.isfinite(high), high, np.inf)
        at += len(stops)
        limit = self.ch.torque_limit_nm  # tau = M_a qdd + h_a - J_a^T f within its limit (the last rows)
        rows[at:, :nv], rows[at:, nv:] = M[act], -Jp[:, act].T
        lo[at:], hi[at:] = -limit - bias[act], limit - bias[act]
        sense = np.zeros(rows.shape[0], dtype=np.int32)
        sense[:n_eq] = EQUALITY
        return rows, lo, hi, sense

    def _constant_parts(self) -> None:
        """What does not change between control steps, made once: the QP's ground rows - per point its floor (f_z)
        and the friction pyramid's four faces (+-f_x +-f_y <= mu f_z: MuJoCo's pyramid, scaled) -, a unit row per
        actuated joint for its stops, and the foot points' geoms, bodies, drop to their lowest point and Jacobian
        buffer."""
        nv, n_pts, mu = self.nv, len(self.points), self.config.friction_coef
        n = nv + 3 * n_pts
        ground = np.zeros((5 * n_pts, n))
        lo, hi = np.zeros(5 * n_pts), np.zeros(5 * n_pts)
        for p in range(n_pts):
            fx, fy, fz = nv + 3 * p, nv + 3 * p + 1, nv + 3 * p + 2
            ground[5 * p, fz] = 1.0
            for r, (sx, sy) in enumerate(((1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0))):
                ground[5 * p + 1 + r, [fx, fy, fz]] = sx, sy, -mu
                lo[5 * p + 1 + r], hi[5 * p + 1 + r] = -np.inf, 0.0
        self._ground_rows, self._ground_lo, self._ground_hi = ground, lo, hi
        self._stop_rows = np.zeros((len(self.act_dofs), n))
        self._stop_rows[np.arange(len(self.act_dofs)), self.act_dofs] = 1.0
        self._point_ids = list(self.points)
        self._point_drop = np.zeros((n_pts, 3))  # from a point's centre to its lowest point
        self._point_drop[:, 2] = self.model.geom_size[self._point_ids, 0]
        self._point_bodies = [int(self.model.geom_bodyid[g]) for g in self.points]
        self._jacp = np.empty((n_pts, 3, self.model.nv))
        self._foot_point_index = [[self.points.index(g) for g in pair] for pair in self.ch.foot_points]
