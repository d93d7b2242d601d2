"""The reactive momentum balance controller (ABC section 3; Macchietto et al. 2009),
with torques the ground can carry.

Per control step it plans joint accelerations qdd by a small QP

    min  b_l |Ldot_x,des - (A_x qdd + a_x)|^2 + b_h |Hdot_des - (A_h qdd + a_h)|^2
         + b_t |W (qdd_des - qdd)|^2 + w_r sum_{rolling feet} |foot pitch acc - its target|^2 + eps |qdd|^2
    s.t. support rows: each foot's contact points do not accelerate (a flat foot: x, z and
         pitch; a foot rolling on its heel or toe: that point's x and z)
         the ground wrench  w = A qdd + a + (0, m g, 0)  is one the ground can push with:
           every loaded heel/toe point carries at least f_min,  |F_x| <= mu F_z,
           CoP inside the support (rolling: exactly at the rolling edge)

with  Ldot_x,des = k_l m (c_r - c) + d_l (m cdot_r - L_x),   c_r = s + d(t)  (CMRT),
      Hdot_des   = [(p_des - c) x (Ldot_des - m g)]_y,       p_des = s (support centre),
      qdd_des    = k_t (q_r - q) + d_t (qd_r - qd) + qdd_r.

The torques are the inverse dynamics of that plan with the ground forces it implies,
split over the heel/toe points that carry load:  tau = [M qdd + h - J_c' f]_actuated.
The plan satisfies the floating-base rows exactly with a wrench the ground can give
(unilateral, inside the friction cone, CoP inside the support), so the torques ask
nothing of the ground that it cannot do: what MuJoCo does with them is what was
planned. When the motion asks for more than the feet can give, the QP trades tracking
against momentum - it never pulls on the floor. A loss of balance is then what it is
physically: the CoM drifting past the point of no return and toppling over an edge
of the feet (``cmrt.sim.balance``), not a launch (docs/controller.md has the measurements).

Contact modes follow the measured contact (the heel/toe contact LCP, decided by the
physics): a foot whose toe (heel) is off the ground - pushed over by something the
controller does not model, a prop or a push - is planned as rolling on its heel (toe),
with its pitch acceleration steered softly (weight w_r) back toward flat. The
controller never plans to lift a point itself.

Everything is vectorised over a leading axis of n simulations (one CMA-ES generation
stepped in lockstep with ``mujoco.batch.Batch``); a single clip is the case n = 1, so
there is one implementation and batched and serial objectives agree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cmrt.body.character import FOOT_POINT_RADIUS_M, GRAVITY_M_S2, Character
from cmrt.control import kernel
from cmrt.control.kernel import AIR, FLAT, HEEL, TOE
from cmrt.control.planar import PlanarKinematics

# -DUAL_REGULARIZATION on the multipliers' diagonal of the KKT matrix: redundant support rows
# (both feet asking the same vertical acceleration of a straight-kneed body: the legs' Jacobians
# are singular at the knee limit) then solve in the least-squares sense instead of making the
# matrix singular; a consistent row is met to ~1e-9 of its multiplier.
DUAL_REGULARIZATION = 1e-9


@dataclass(frozen=True)
class ControllerConfig:
    """Gains and weights. Values and why: docs/controller.md."""

    k_l: float = 10.0  # 1/s^2, CoM stiffness of the linear-momentum objective
    d_l: float = 2.0 * math.sqrt(10.0)  # 1/s, its damping (critical for k_l)
    k_t: float = 100.0  # 1/s^2, joint tracking stiffness
    d_t: float = 20.0  # 1/s, joint tracking damping (critical for k_t)
    beta_l: float = 0.1  # weight of the linear-momentum objective
    beta_h: float = 0.1  # weight of the angular-momentum objective
    beta_t: float = 1.0  # weight of the tracking objective
    weight_upper: float = 1.0  # W for lumbar, neck and arms
    weight_leg: float = 1.0  # W for hips, knees, ankles
    weight_root_pitch: float = 1.0  # W for the trunk's absolute pitch
    # ...and while a footstep plan walks (cmrt.control.stepping.GaitPattern): its firmer linear-momentum objective
    # otherwise pitched the trunk to and fro, 20-25 deg forward every swing of a 0.6 m/s walk; held this firmly the
    # thorax stays within 2-9 deg (docs/stepping.md, *The walking pattern*)
    gait_weight_root_pitch: float = 20.0
    gait_weight_lumbar: float = 2.0
    regularization: float = 1e-6  # eps on |qdd|^2, keeps the KKT matrix regular
    control_every: int = 4  # physics steps per control step: 125 Hz at the 2 ms step (ABC: 60-120 Hz)
    friction_coef: float = 0.8  # planned |F_x| <= mu F_z (the MJCF's floor friction is 1.0)
    # Every loaded heel/toe point is planned to carry at least this: on MuJoCo's soft contact a point planned
    # below ~45 N goes slack for a physics step now and then (the plan is followed through held torques), and the
    # executed CoP jumps to the other end of the foot (measured over random CMRTs of the fast bend: 0.5 % of the
    # control steps at 35-40 N, none at 40-50 N with this floor; docs/controller.md). Where the load is too low to
    # give every point this and keep the middle half of the feet (F_z < 2 x points x this), the floor per point is
    # half an equal share instead: the planned CoP never closes in on the support centre.
    min_point_force_n: float = 50.0
    # The plan's vertical force never falls below this per loaded point (160 N, 0.23 body weights, on four): the
    # body is never planned to drop faster than that (a reference that asks for it is not followed as written).
    min_vertical_force_per_point_n: float = 40.0
    support_damping: float = 20.0  # 1/s, support rows ask the contact points' velocity to decay
    roll_weight: float = 1.0  # w_r: cost of a rolling foot's pitch acceleration away from its return-to-flat target
    roll_k: float = 100.0  # 1/s^2, return-to-flat stiffness of a rolling foot
    roll_d: float = 20.0  # 1/s, its damping
    swing_weight: float = 10.0  # weight of the swing foot's task-space objective (docs/stepping.md)
    swing_k: float = 400.0  # 1/s^2, swing foot stiffness about its planned path
    swing_d: float = 40.0  # 1/s, its damping (critical for swing_k)
    swing_leg_tracking: float = 0.01  # factor on the swing leg's joint-tracking weight while it swings
    # Motor limits and joint stops as rows of the QP (issue 25), so the plan is one the motors can carry out and
    # never leans on a stop; off, torques beyond a limit are clipped after the solve (the v0.2 controller, kept
    # bit for bit until the library and the docs' tables are re-measured with the limits in the plan).
    limits_in_plan: bool = True
    # Delay of the balance feedback (s; whole control steps): the linear-momentum objective acts on the CoM
    # position and velocity sensed this long ago, while the plan's dynamics and contact rows use the present
    # state and the CMRT (the anticipation) is not delayed. 0: the v0.2 controller, bit for bit (issue 25;
    # docs/controller.md). Applied by cmrt.simulate, which keeps the history.
    feedback_delay_s: float = 0.1
    # Start each control step's QP from the active set the previous step of the same simulation ended on
    # (kernel.solve_qp): 1-2 KKT solves instead of 3-5. The solution comes from the final set alone, so the
    # result only changes where the warm and the cold start end on different sets (docs/performance.md).
    warm_start: bool = True
    stop_k: float = 400.0  # 1/s^2, the plan approaches a joint stop no faster than this spring (docs/controller.md)
    stop_d: float = 40.0  # 1/s, its damping (critical)
    stop_margin_rad: float = 0.02  # the plan keeps this far from every joint stop

    def tracking_weights(self, ch: Character, walking: bool = False) -> np.ndarray:
        """Per-dof weight of joint tracking in the QP (root translation untracked: momentum sets it); ``walking``:
        while a footstep plan walks."""
        w = np.full(ch.nv, self.weight_upper)
        w[ch.root_dofs[0]] = w[ch.root_dofs[1]] = 0.0  # root translation is not tracked
        w[ch.root_dofs[2]] = self.gait_weight_root_pitch if walking else self.weight_root_pitch
        for i, name in enumerate(ch.dof_names):
            if name.split("_")[0] in ("hip", "knee", "ankle"):
                w[i] = self.weight_leg
            elif walking and name == "lumbar":
                w[i] *= self.gait_weight_lumbar
        return w


_FIELDS = ("cdof", "cdof_dot", "cvel", "cinert", "qpos", "qvel", "M", "qfrc_bias", "qfrc_passive", "subtree_com",
           "geom_xpos")


def read_only(x: np.ndarray) -> np.ndarray:
    """A read-only view of ``x`` (the kernel's inputs: numba compiles one signature for read-only arrays)."""
    x = x.view()
    x.flags.writeable = False
    return x


def _as_kernel(x, dtype=np.float64) -> np.ndarray:
    """C-contiguous and read-only, like MuJoCo's bound batch fields: numba compiles one signature
    (a writable copy and a read-only view are different types to it: 30 s of compiling each).
    A bound field passes straight through."""
    if x.__class__ is np.ndarray and not x.flags.writeable and x.flags.c_contiguous and x.dtype == dtype:
        return x
    x = np.ascontiguousarray(x, dtype=dtype)
    return read_only(x) if x.flags.writeable else x


def _shared_rows(r: np.ndarray, buf: np.ndarray, view: np.ndarray) -> np.ndarray:
    """A reference for every row: (nv,) shared ones are copied into ``buf`` (read through ``view``),
    (n, nv) per-row ones pass as they are."""
    if r.ndim == 1 and r.shape == buf.shape[1:]:
        buf[:] = r
        return view
    return _as_kernel(np.broadcast_to(r, (buf.shape[0], r.shape[-1])))


@dataclass(frozen=True)
class ControlOutput:
    """One control step for n simulations."""

    torque_nm: np.ndarray  # (n, nu), clipped to the motor limits
    ground_force_n: np.ndarray  # (n, 2) planned total ground force (x, z)
    cop_x_m: np.ndarray  # (n,) planned CoP
    foot_state: np.ndarray  # (n, 2) FLAT / HEEL / TOE / AIR per foot (right, left)
    saturated: np.ndarray  # (n,) the torques were clipped at a motor limit


class MomentumBalanceController:
    """Computes motor torques for n simulations from their bound MuJoCo fields (cmrt.control.kernel)."""

    def __init__(self, ch: Character, config: ControllerConfig = ControllerConfig()):
        self.ch = ch
        self.config = config
        kin = PlanarKinematics(ch.model)  # the humanoid alone: props come after it in any model
        self.nv, self.nbody, self.nM = ch.model.nv, ch.model.nbody, ch.model.nM
        self.chain = kin.chain.astype(bool)
        self.m_rows, self.m_cols = kin.m_rows.astype(np.int64), kin.m_cols.astype(np.int64)
        self.w2 = np.stack([config.tracking_weights(ch) ** 2, config.tracking_weights(ch, walking=True) ** 2])
        self.actuated = np.array(ch.actuated_dofs, dtype=np.int64)
        self.limits = ch.torque_limit_nm.astype(float)
        # per actuator: torque limit, and the joint range less the stop margin (rows of the QP)
        lo, hi = ch.joint_range_rad()
        self.bounds = np.ascontiguousarray(np.stack([self.limits, lo + config.stop_margin_rad,
                                                     hi - config.stop_margin_rad], axis=1))
        self.mass = ch.mass_kg
        self.points = np.array(ch.foot_point_geoms, dtype=np.int64)  # heel_r, toe_r, heel_l, toe_l
        self.point_bodies = ch.model.geom_bodyid[self.points].astype(np.int64)
        self.leg_dofs = np.array(ch.leg_dofs, dtype=np.int64)
        c = config
        params = np.zeros(kernel.N_PARAMS)
        for index, value in ((kernel.P_KL, c.k_l), (kernel.P_DL, c.d_l), (kernel.P_KT, c.k_t), (kernel.P_DT, c.d_t),
                             (kernel.P_BL, c.beta_l), (kernel.P_BH, c.beta_h), (kernel.P_BT, c.beta_t),
                             (kernel.P_EPS, c.regularization), (kernel.P_G, GRAVITY_M_S2),
                             (kernel.P_MU, c.friction_coef), (kernel.P_FMIN, c.min_point_force_n),
                             (kernel.P_DAMP, c.support_damping), (kernel.P_RW, c.roll_weight), (kernel.P_RK, c.roll_k),
                             (kernel.P_RD, c.roll_d), (kernel.P_RADIUS, FOOT_POINT_RADIUS_M),
                             (kernel.P_DUALREG, DUAL_REGULARIZATION), (kernel.P_SW, c.swing_weight),
                             (kernel.P_SK, c.swing_k), (kernel.P_SD, c.swing_d),
                             (kernel.P_SWT, c.swing_leg_tracking), (kernel.P_JK, c.stop_k),
                             (kernel.P_JD, c.stop_d), (kernel.P_LIMITS, float(c.limits_in_plan)),
                             (kernel.P_WARM, float(c.warm_start)),
                             (kernel.P_FZMIN, c.min_vertical_force_per_point_n)):
            params[index] = value
        self.params = params
        self.n_rows = kernel.n_rows(self.actuated.size)  # width of the warm-start arrays
        self._per_n: dict[int, dict] = {}

    def _constants(self, n: int) -> dict:
        """Per batch size: the defaults and the buffers shared references are spread into, made once
        (a control step runs ~400 times per clip; allocating them each time was measurable)."""
        c = self._per_n.get(n)
        if c is None:
            bufs = [np.empty((n, self.nv)) for _ in range(3)]
            c = self._per_n[n] = {
                "rows": np.arange(n),  # simulation i reads row i (writable int64, as the compiled loop's rows)
                "refs": [(buf, read_only(buf)) for buf in bufs],
                "mass": read_only(np.full(n, self.mass)), "no_swing": read_only(np.full(n, -1.0)),
                "no_target": read_only(np.zeros((n, kernel.N_SWING))),
                "cold": read_only(np.zeros((n, self.n_rows), bool)), "warm_out": np.zeros((n, self.n_rows), bool),
                "no_load": (np.zeros((n, 2)), np.zeros((n, 3)), np.zeros(0, np.int64)),  # read, never written
                "no_field": (np.zeros((n, 0, 3)), np.zeros((n, 0, 3)))}
        return c

    @staticmethod
    def foot_states(in_contact: np.ndarray) -> np.ndarray:
        """(n, 2) support state per foot from (n, 4) heel/toe contact flags (heel_r, toe_r, heel_l, toe_l)."""
        heel, toe = in_contact[:, 0::2], in_contact[:, 1::2]
        return np.select([heel & toe, heel, toe], [FLAT, HEEL, TOE], AIR)

    def torques(self, f: dict[str, np.ndarray], q_ref, qd_ref, qdd_ref, com_ref_x, com_ref_vel_x, cop_des_x,
                in_contact: np.ndarray, mass_kg: np.ndarray | None = None, swing_foot: np.ndarray | None = None,
                swing_target: np.ndarray | None = None, warm: np.ndarray | None = None,
                load: tuple | None = None, field: tuple | None = None) -> ControlOutput:
        """Torques for n simulations. ``f`` holds (n, ...) arrays of the MuJoCo fields at the current state:
        qpos, qvel, cdof, cdof_dot, cvel, cinert, M, qfrc_bias, qfrc_passive, subtree_com, geom_xpos.
        References are (nv,) (shared) or (n, nv) (one per simulation); CoM/CoP targets are (n,);
        ``in_contact`` (n, 4) says which heel/toe points touch the ground; ``mass_kg`` (n,) the character's
        mass with what it carries (default: its own). ``swing_foot`` (n,): -1, or the foot (0 right, 1 left)
        that swings toward ``swing_target`` (n, 10): heel point x, z, foot pitch, their rates and accelerations,
        the stance knee's extra bend
        (``cmrt.control.stepping``); default: no foot swings. ``warm`` (n, n_rows) bool: each simulation's QP
        active set from its previous control step, updated in place once every plan has been found (a singular
        plan raises ``LinAlgError`` and leaves it as it was); None: every QP starts cold. ``field``: (forces (n, nb, 3),
        points (n, nb, 3)), the support's field on each humanoid body (``cmrt.body.surface.Support.field``: force
        x, z at the body's CoM and torque about y); None: a still, level floor."""
        n = f["qvel"].shape[0]
        c = self._constants(n)
        tau = np.empty((n, self.actuated.size))
        info = np.empty((n, kernel.N_INFO))
        kernel.control_step(
            c["rows"], tuple(_as_kernel(f[k]) for k in _FIELDS),
            (self.chain, self.m_rows, self.m_cols, self.points, self.point_bodies, self.leg_dofs, self.actuated,
             self.bounds, self.w2, self.params),
            (*(_shared_rows(r, buf, view) for r, (buf, view) in zip((q_ref, qd_ref, qdd_ref), c["refs"], strict=True)),
             _as_kernel(com_ref_x), _as_kernel(com_ref_vel_x), _as_kernel(cop_des_x)),
            (_as_kernel(in_contact, np.bool_), c["mass"] if mass_kg is None else _as_kernel(mass_kg),
             c["no_swing"] if swing_foot is None else _as_kernel(swing_foot),
             c["no_target"] if swing_target is None else _as_kernel(swing_target)),
            (c["cold"] if warm is None else warm, c["warm_out"]),
            tuple(c["no_load"] if load is None else load) + tuple(c["no_field"] if field is None else field),
            (tau, info),
        )
        if warm is not None:
            np.copyto(warm, c["warm_out"])
        return ControlOutput(torque_nm=tau, ground_force_n=info[:, :2], cop_x_m=info[:, 2],
                             foot_state=info[:, 3:5].astype(int), saturated=info[:, 5] > 0)
