"""What a keyed motion asks of the ground and of the motors with both feet flat: exact inverse dynamics.

The driving joints follow the task's reference exactly; both feet stay flat where they settled (the right heel
at x = -0.06 m, as ``feet_flat_qpos`` places them); both ankles turn by the keyed angle plus a shift delta(t).
With the feet fixed, a shift of the ankles turns everything above them rigidly about the ankle axis, by -delta
in pitch (a positive ankle angle tilts the foot's front down against the shank, so with the foot held the shank
leans back). That is how the controller, and a CMRT through it, moves the CoM horizontally, so
``cmrt.motion.feasibility`` searches over delta.

The keyed motion is placed once (:func:`keyed_motion`: root by forward kinematics from the feet, its rates from
the heel's Jacobian and its ``mj_jacDot``, all analytic); a shift is then a rotation of that placement about the
fixed ankle axis (:func:`shifted_state`), and ``mj_inverse`` on the humanoid with every constraint disabled gives
the generalized forces at every sample. The root dofs' forces are the ground's (F_x, F_z and their moment); the
motors' torques are the rest less the ground force on the feet, split over the four heel/toe points as the
controller splits it (``cmrt.control.kernel``: F_x equally, F_z by the linear lever rule for the CoP).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import mujoco
import numpy as np

from cmrt.body.character import FOOT_POINT_RADIUS_M, GRAVITY_M_S2, MODEL_PATH, STANCE_HEEL_X_M, character
from cmrt.motion.task import Task

#: The samples' step (s): the motions' quintic easings are smooth on it (the fastest shipped one, the 0.3 s
#: bend, spans 60 samples), and a check stays well under a second.
DT_S = 0.005


@functools.cache
def _free_model() -> mujoco.MjModel:
    """The humanoid with every constraint disabled: ``mj_inverse`` then leaves the whole ground force to the
    root dofs (and no joint stop or soft contact adds one of its own)."""
    m = mujoco.MjModel.from_xml_path(str(MODEL_PATH))
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    return m


@dataclass(frozen=True, eq=False)
class FlatFootMotion:
    """A task's reference sampled on [0, clip] and placed with both feet flat (no ankle shift)."""

    t_s: np.ndarray  # (n,)
    qpos: np.ndarray  # (n, nv)
    qvel: np.ndarray
    qacc: np.ndarray
    pelvis_m: np.ndarray  # (n, 2): x, z of the pelvis origin (the root hinge's and the hips' axis)
    knee_m: np.ndarray  # (n, 2): the knees' axis
    com_m: np.ndarray  # (n, 2): the whole body's CoM
    com_vel_m_s: np.ndarray  # (n, 2)
    ankle_m: np.ndarray  # (2,): the ankles' axis (fixed: the feet do not move)
    heel_x_m: float  # the heel and toe points of both feet (they are side by side)
    toe_x_m: float
    upper_mass_kg: float  # everything above the ankles (the body less its feet)
    feet_com_m: np.ndarray  # (2,)

    @property
    def n(self) -> int:
        return self.t_s.size


@dataclass(frozen=True, eq=False)
class Loads:
    """What a motion asks for at every sample: the ground's force and moment, and each motor's torque."""

    t_s: np.ndarray
    force_n: np.ndarray  # (n, 2): ground force F_x, F_z on the feet
    heel_moment_nm: np.ndarray  # (n,): F_z (CoP - heel x): the toe points' share times the foot's length
    torque_nm: np.ndarray  # (n, nu): per actuator, in actuator order
    com_m: np.ndarray  # (n, 2)
    heel_x_m: float
    toe_x_m: float

    @property
    def cop_x_m(self) -> np.ndarray:
        """x of the centre of pressure (NaN where the ground would have to pull)."""
        fz = self.force_n[:, 1]
        return np.where(fz > 0, self.heel_x_m + self.heel_moment_nm / np.where(fz > 0, fz, 1.0), np.nan)

    def point_forces_n(self) -> tuple[np.ndarray, np.ndarray]:
        """(heel, toe) vertical force per foot: ``lever_split``."""
        return lever_split(self.force_n[:, 1], self.heel_moment_nm, self.toe_x_m - self.heel_x_m)


def lever_split(fz_n: np.ndarray, heel_moment_nm: np.ndarray, foot_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(heel, toe) vertical force per foot as the controller splits F_z (``cmrt.control.kernel``): by the linear
    lever rule for the CoP, each foot carrying half. Linear in the wrench: no division by F_z."""
    toe = 0.5 * heel_moment_nm / foot_m
    return 0.5 * fz_n - toe, toe


def keyed_motion(task: Task, dt_s: float = DT_S) -> FlatFootMotion:
    """The task's reference over its clip, every ``dt_s``, with both feet flat and the keyed ankle."""
    ch = character()
    m = _free_model()
    d = mujoco.MjData(m)
    t = np.linspace(0.0, task.clip_s, int(round(task.clip_s / dt_s)) + 1)
    q, qd, qdd = (np.array(a, dtype=float) for a in task.reference(t))
    heel_g, toe_g = ch.foot_points[0]
    foot = ch.foot_bodies[0]
    knee = ch.dof("knee_r")
    pelvis, knee_at, com, com_vel = (np.empty((t.size, 2)) for _ in range(4))
    jac, jac_dot, jac_com = np.empty((3, m.nv)), np.empty((3, m.nv)), np.empty((3, m.nv))
    target = np.array([STANCE_HEEL_X_M, FOOT_POINT_RADIUS_M])  # the right heel point's centre (feet_flat_qpos)
    for k in range(t.size):
        d.qpos[:] = q[k]
        d.qpos[:2] = 0.0
        mujoco.mj_kinematics(m, d)
        q[k, :2] = target - d.geom_xpos[heel_g, [0, 2]]
        d.qpos[:] = q[k]
        d.qvel[:] = qd[k]
        d.qvel[:2] = 0.0
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        point = d.geom_xpos[heel_g].copy()
        mujoco.mj_jac(m, d, jac, None, point, foot)
        qd[k, :2] = -(jac[[0, 2], 2:] @ qd[k, 2:])  # the heel does not move
        d.qvel[:] = qd[k]
        mujoco.mj_comVel(m, d)
        mujoco.mj_jacDot(m, d, jac_dot, None, point, foot)
        qdd[k, :2] = -(jac[[0, 2], 2:] @ qdd[k, 2:] + (jac_dot @ qd[k])[[0, 2]])  # nor accelerate
        mujoco.mj_jacSubtreeCom(m, d, jac_com, 1)
        pelvis[k] = d.xanchor[m.dof_jntid[ch.root_dofs[2]], [0, 2]]
        knee_at[k] = d.xanchor[m.dof_jntid[knee], [0, 2]]
        com[k] = d.subtree_com[1, [0, 2]]
        com_vel[k] = (jac_com @ qd[k])[[0, 2]]
    feet = list(ch.foot_bodies)
    feet_mass = float(m.body_mass[feet].sum())
    d.qpos[:] = q[0]
    mujoco.mj_kinematics(m, d)
    return FlatFootMotion(
        t_s=t, qpos=q, qvel=qd, qacc=qdd, pelvis_m=pelvis, knee_m=knee_at, com_m=com, com_vel_m_s=com_vel,
        ankle_m=d.xanchor[m.dof_jntid[ch.dof("ankle_r")], [0, 2]].copy(),
        heel_x_m=float(d.geom_xpos[heel_g, 0]), toe_x_m=float(d.geom_xpos[toe_g, 0]),
        upper_mass_kg=ch.mass_kg - feet_mass,
        feet_com_m=(m.body_mass[feet] @ d.xipos[feet][:, [0, 2]]) / feet_mass)


def _turn(v: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """(n, 2) vectors (x, z) turned by pitch ``phi`` about +y (a positive pitch tilts up toward +x)."""
    c, s = np.cos(phi), np.sin(phi)
    return np.stack([c * v[:, 0] + s * v[:, 1], -s * v[:, 0] + c * v[:, 1]], axis=1)


def _turned_point(p: np.ndarray, rates: tuple[np.ndarray, np.ndarray], motion: FlatFootMotion,
                  shift: tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A point of the body above the ankles (position ``p``, its velocity and acceleration ``rates`` in the keyed
    motion) when that body turns by phi = -delta about the ankles: position, velocity, acceleration."""
    phi, phi_d, phi_dd = (-x for x in shift)
    r = p - motion.ankle_m
    v, a = rates
    perp = lambda x: _turn(x, phi + 0.5 * np.pi)  # noqa: E731  d/dphi of the turn
    w, w2 = phi_d[:, None], phi_dd[:, None]
    return (motion.ankle_m + _turn(r, phi), _turn(v, phi) + w * perp(r),
            _turn(a, phi) + 2 * w * perp(v) + w2 * perp(r) - w**2 * _turn(r, phi))


def shifted_state(motion: FlatFootMotion, shift: tuple[np.ndarray, np.ndarray, np.ndarray]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """qpos, qvel, qacc (n, nv) of the keyed motion with both ankles shifted by delta (and its two rates)."""
    ch = character()
    delta, delta_d, delta_dd = shift
    q, qd, qdd = motion.qpos.copy(), motion.qvel.copy(), motion.qacc.copy()
    for arr, x in ((q, delta), (qd, delta_d), (qdd, delta_dd)):
        arr[:, list(ch.ankle_dofs)] += x[:, None]
        arr[:, ch.root_dofs[2]] -= x  # root pitch = -(hip + knee + ankle): the feet stay flat
    pelvis_rates = (motion.qvel[:, :2], motion.qacc[:, :2])  # the root slides move the pelvis origin
    p, v, a = _turned_point(motion.pelvis_m, pelvis_rates, motion, shift)
    offset = motion.pelvis_m - motion.qpos[:, :2]
    q[:, :2], qd[:, :2], qdd[:, :2] = p - offset, v, a
    return q, qd, qdd


def loads(motion: FlatFootMotion, shift: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> Loads:
    """The ground's wrench and the motors' torques at every sample, for ankles shifted by ``shift`` (delta,
    its rate and acceleration, (n,) each; None: the keyed ankle)."""
    if shift is None:
        shift = (np.zeros(motion.n),) * 3
    q, qd, qdd = shifted_state(motion, shift)
    qfrc = generalized_forces(q, qd, qdd)
    ch = character()
    force = qfrc[:, :2]
    phi = -shift[0]
    pelvis = motion.ankle_m + _turn(motion.pelvis_m - motion.ankle_m, phi)
    knee = motion.ankle_m + _turn(motion.knee_m - motion.ankle_m, phi)
    # the root hinge's force is the ground's moment about the pelvis origin, the forces acting on the floor (z = 0)
    heel_moment = (pelvis[:, 0] - motion.heel_x_m) * force[:, 1] - pelvis[:, 1] * force[:, 0] - qfrc[:, 2]
    heel_fz, toe_fz = lever_split(force[:, 1], heel_moment, motion.toe_x_m - motion.heel_x_m)
    ground = np.zeros_like(qfrc)  # J_c' f: the ground force on each foot as generalized forces
    axes = {"hip": pelvis, "knee": knee, "ankle": np.broadcast_to(motion.ankle_m, pelvis.shape)}
    for name, o in axes.items():
        # a hinge about +y at o: a force (f_x, f_z) at (x, 0) gives f_x (0 - o_z) - f_z (x - o_x)
        gen = (-0.5 * force[:, 0] * o[:, 1] - heel_fz * (motion.heel_x_m - o[:, 0])
               - toe_fz * (motion.toe_x_m - o[:, 0]))
        for side in ("r", "l"):
            ground[:, ch.dof(f"{name}_{side}")] = gen
    torque = (qfrc - ground)[:, list(ch.actuated_dofs)]
    return Loads(t_s=motion.t_s, force_n=force, heel_moment_nm=heel_moment, torque_nm=torque,
                 com_m=_com(motion, phi), heel_x_m=motion.heel_x_m, toe_x_m=motion.toe_x_m)


def _com(motion: FlatFootMotion, phi: np.ndarray) -> np.ndarray:
    """The whole body's CoM with the body above the ankles turned by ``phi``."""
    ch = character()
    feet_mass = ch.mass_kg - motion.upper_mass_kg
    upper = (ch.mass_kg * motion.com_m - feet_mass * motion.feet_com_m) / motion.upper_mass_kg
    turned = motion.ankle_m + _turn(upper - motion.ankle_m, phi)
    return (motion.upper_mass_kg * turned + feet_mass * motion.feet_com_m) / ch.mass_kg


def generalized_forces(qpos: np.ndarray, qvel: np.ndarray, qacc: np.ndarray) -> np.ndarray:
    """``mj_inverse`` at every row (n, nv): the generalized forces the motion needs, the ground's at the root."""
    m = _free_model()
    d = mujoco.MjData(m)
    out = np.empty_like(qpos)
    for k in range(qpos.shape[0]):
        d.qpos[:], d.qvel[:], d.qacc[:] = qpos[k], qvel[k], qacc[k]
        mujoco.mj_inverse(m, d)
        out[k] = d.qfrc_inverse
    return out


def body_weight_n() -> float:
    """The character's weight (N)."""
    return character().mass_kg * GRAVITY_M_S2
