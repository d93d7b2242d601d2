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
the motors are asked for. The step's arithmetic is compiled (``cmrt.control.spatial_kernel``: MuJoCo's M and bias
forces, the centroidal momentum and the Jacobians from MuJoCo's com-based fields as the planar kernel's, checked
against MuJoCo's own functions) and its QP is ``cmrt.control.dual_qp``'s, warm-started from the last step's working
set; this class keeps what lasts between steps (the references, the delayed feedback, the working set).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from cmrt.body.character import GRAVITY_M_S2, Character
from cmrt.control import dual_qp
from cmrt.control import spatial_kernel as sk
from cmrt.control.controller import ControllerConfig
from cmrt.control.planar import PlanarKinematics
from cmrt.errors import CmrtError

N_BASE = sk.N_BASE


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


@dataclass(frozen=True)
class SpatialTargetTable:
    """A motion's targets at every control step of a clip, made before it runs (a motion's references depend on
    time alone): row ``i`` is control step ``i``'s ``SpatialTargets``. A field left None is the standing default at
    every step; ``swing_foot`` is -1 in a row without a foot in the air (its path's row is then not read). A
    compiled clip (``cmrt.sim.spatial_loop``) reads the arrays, a clip with a prop asks ``at`` each step."""

    com_xy_m: np.ndarray | None = None  # (n, 2)
    com_vel_xy_m_s: np.ndarray | None = None  # (n, 2)
    cop_xy_m: np.ndarray | None = None  # (n, 2)
    q_ref: np.ndarray | None = None  # (n, nq)
    qd_ref: np.ndarray | None = None  # (n, nv)
    qdd_ref: np.ndarray | None = None  # (n, nv)
    swing_foot: np.ndarray | None = None  # (n,) int: 0 right, 1 left, -1 none
    swing_pos_m: np.ndarray | None = None  # (n, 3)
    swing_vel_m_s: np.ndarray | None = None  # (n, 3)

    def at(self, i: int) -> SpatialTargets:
        """Control step ``i``'s targets."""
        swing = -1 if self.swing_foot is None else int(self.swing_foot[i])

        def row(values: np.ndarray | None) -> np.ndarray | None:
            return None if values is None else values[i]
        return SpatialTargets(row(self.com_xy_m), row(self.com_vel_xy_m_s), row(self.cop_xy_m), row(self.q_ref),
                              row(self.qd_ref), row(self.qdd_ref), swing,
                              row(self.swing_pos_m) if swing >= 0 else None,
                              row(self.swing_vel_m_s) if swing >= 0 else None)


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
        # the planar floor per heel or toe point, shared by the points across that end of a 3D foot: the same
        # force per length of foot, so the same share of the foot stays open to the CoP
        self.point_floor_n = config.min_point_force_n * 4 / len(self.points)
        self.mass_kg = float(self.model.body_subtreemass[1])  # with what the forearms carry (a handed-over ball)
        step_s = control_step_s if control_step_s is not None else m.opt.timestep * config.control_every
        self.delay_steps = int(round(config.feedback_delay_s / step_s))
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
        holding it equally - a gripped ball moving with them, its weight and its inertia in the plan's dynamics:
        planning with a held ball's inertia, not only last step's pull - the pull alone, measured one step late,
        left the arms' rotation about their own axes (whose inertia the 7 kg ball outweighs fifty times) swinging
        0.4 rad."""
        self.mass_kg = float(self.model.body_subtreemass[1])
        self.start(d)
        t = self._targets
        swing_at, swing_rate = ((targets.swing_pos_m, targets.swing_vel_m_s) if targets.swing_foot >= 0
                                else (self._no_point, self._no_point))
        def given(value, default: np.ndarray) -> np.ndarray:
            return default if value is None else np.asarray(value, float)
        sk.write_targets(t, self.com_ref_m, given(targets.com_xy_m, self.com_ref_m[:2]),
                         given(targets.com_vel_xy_m_s, self._no_point[:2]), given(targets.cop_xy_m, self.cop_ref_m),
                         int(targets.swing_foot), np.asarray(swing_at, float), np.asarray(swing_rate, float),
                         0.0 if held_mass is None else float(held_mass[0]), self.mass_kg)
        held_bodies = self._no_bodies
        if held_mass is not None:
            t[sk.T_HELD_AT:sk.T_HELD_AT + 3] = held_mass[1]
            held_bodies = np.asarray(held_mass[2], dtype=np.int64)
        refs = (self.q_ref if targets.q_ref is None else np.asarray(targets.q_ref, float),
                self._still if targets.qd_ref is None else np.asarray(targets.qd_ref, float),
                self._still if targets.qdd_ref is None else np.asarray(targets.qdd_ref, float))
        fields = (d.cdof, d.cdof_dot, d.cvel, d.cinert, d.qpos, d.qvel, d.M, d.qfrc_bias, d.subtree_com,
                  d.geom_xpos, d.xpos, d.xquat)
        torque, forces, cop, status, limited = sk.plan_step(
            fields, self._body, self._gains, t, refs, np.asarray(loaded, dtype=np.bool_),
            self._still if load_gen is None else np.asarray(load_gen, float)[:self.nv], held_bodies,
            self._history, self._count, self._active)
        self.infeasible = not limited  # no plan within the stops and the motors' limits (a fall): planned without
        if status != dual_qp.OPTIMAL:  # the limits' rows, the torques clipped after the solve
            raise CmrtError(f"the 3D balance QP has no solution (status {status})")
        if not np.isfinite(torque).all():  # never hand MuJoCo a NaN (it resets the clip, 'simulation is unstable')
            raise CmrtError("the 3D balance QP gave torques that are not finite")
        return SpatialPlan(torque, forces, cop)

    def start(self, d: mujoco.MjData) -> None:
        """Hold what the first control step finds (``d`` after mj_forward): the CoM where it is, the CoP at the
        feet's centre - the standing defaults of every later step."""
        if self.com_ref_m is None:
            self.com_ref_m = d.subtree_com[1].copy()
            self.cop_ref_m = d.geom_xpos[self._point_ids, :2].mean(axis=0)

    def table_arrays(self, table: SpatialTargetTable, n: int) -> tuple[np.ndarray, ...]:
        """``table``'s ``n`` rows as the compiled clip reads them, every default filled in as ``plan`` fills it
        (after ``start``): (CoM xy, its rate, CoP xy, q_ref, qd_ref, qdd_ref, swing foot, its path, its rate)."""
        def full(values: np.ndarray | None, default: np.ndarray) -> np.ndarray:
            source = np.broadcast_to(default, (n, *default.shape)) if values is None else values[:n]
            return np.ascontiguousarray(source, dtype=float)
        return (full(table.com_xy_m, self.com_ref_m[:2]), full(table.com_vel_xy_m_s, np.zeros(2)),
                full(table.cop_xy_m, self.cop_ref_m), full(table.q_ref, self.q_ref),
                full(table.qd_ref, self._still), full(table.qdd_ref, self._still),
                np.full(n, -1, dtype=np.int64) if table.swing_foot is None
                else np.ascontiguousarray(table.swing_foot[:n], dtype=np.int64),
                full(table.swing_pos_m, np.zeros(3)), full(table.swing_vel_m_s, np.zeros(3)))

    def compiled_parts(self) -> tuple:
        """What the compiled clip hands ``spatial_kernel.plan_step`` beside the data and the targets: (the body's
        index structure, the gains, the targets' buffer, no held bodies, no load, the feedback's history and count,
        the working set) - the controller's own arrays, so its state is the clip's after the run."""
        return (self._body, self._gains, self._targets, self._no_bodies, self._still, self._history, self._count,
                self._active)

    def _constant_parts(self) -> None:
        """What the compiled step (``spatial_kernel.plan_step``) reads that does not change between control steps:
        the body's index structure, stops, limits and contact points, the gains; and its state across steps (the
        delayed feedback's history, the QP's working set)."""
        m, c, ch = self.model, self.config, self.ch
        kin = PlanarKinematics(m)  # the clip's model: the humanoid's bodies and dofs lead, a prop's tree after them
        self._point_ids = list(self.points)
        foot_points = np.array([[self.points.index(g) for g in pair] for pair in ch.foot_points], dtype=np.int64)
        self._body = (
            np.ascontiguousarray(kin.chain[:ch.model.nbody, :self.nv]), kin.m_rows.astype(np.int64),
            kin.m_cols.astype(np.int64), self.act_dofs.astype(np.int64), self.act_qpos.astype(np.int64),
            np.array(self.stops[0], float), np.array(self.stops[1], float),  # copies: the character's are shared
            np.array(ch.torque_limit_nm, float), np.array(self.gear, float),
            np.array(self._point_ids, dtype=np.int64),
            np.array([int(m.geom_bodyid[g]) for g in self.points], dtype=np.int64),
            np.array(m.geom_size[self._point_ids, 0], float),  # a point's drop from its centre to its lowest
            np.array(ch.foot_bodies, dtype=np.int64), foot_points)
        gains = np.empty(sk.N_GAINS)
        for index, value in ((sk.G_KL, c.k_l), (sk.G_DL, c.d_l), (sk.G_KT, c.k_t), (sk.G_DT, c.d_t),
                             (sk.G_BL, c.beta_l), (sk.G_BH, c.beta_h), (sk.G_BT, c.beta_t),
                             (sk.G_EPS, c.regularization), (sk.G_MU, c.friction_coef),
                             (sk.G_FLOOR, self.point_floor_n), (sk.G_DAMP, c.support_damping),
                             (sk.G_SW, c.swing_weight), (sk.G_SK, c.swing_k), (sk.G_SD, c.swing_d),
                             (sk.G_JK, c.stop_k), (sk.G_JD, c.stop_d), (sk.G_GRAVITY, GRAVITY_M_S2)):
            gains[index] = value
        self._gains = gains
        self._targets = np.zeros(sk.N_TARGETS)
        self._still = np.zeros(self.nv)
        self._no_point = np.zeros(3)  # a default rate, or a path not read
        self._no_bodies = np.zeros(0, dtype=np.int64)
        self._history = np.zeros((self.delay_steps + 1, 6))  # the CoM and its velocity, the last control steps'
        self._count = np.zeros(1, dtype=np.int64)
        self._active = np.zeros(sk.n_rows(len(self.act_dofs), len(self.points)), dtype=np.int8)  # the QP's
