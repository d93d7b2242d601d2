"""Planar centroidal momentum matrix A and its bias a = Adot qd, from MuJoCo.

Rows are [L_x, L_z, H_y]: horizontal and vertical linear momentum (kg m/s) and pitch
angular momentum about the CoM (kg m^2/s), so that momentum = A qd and its rate =
A qdd + a. MuJoCo has no built-in for the bias; we take a central finite difference
of A along qd (two extra kinematics passes on a scratch MjData). Error O(eps^2) with
eps = 1e-5 s: ~1e-9 relative, checked against MuJoCo in tests/sim/test_physics.py.
"""

from __future__ import annotations

import mujoco
import numpy as np

FD_EPS_S = 1e-5


def centroidal_momentum_matrix(model: mujoco.MjModel, data: mujoco.MjData, out: np.ndarray | None = None) -> np.ndarray:
    """A (3 x nv) at the current kinematics (needs mj_kinematics + mj_comPos done)."""
    nv = model.nv
    out = np.empty((3, nv)) if out is None else out
    jacp = np.empty((3, nv))
    mujoco.mj_jacSubtreeCom(model, data, jacp, 1)
    ang = np.empty((3, nv))
    mujoco.mj_angmomMat(model, data, ang, 1)
    m = model.body_subtreemass[1]
    out[0] = m * jacp[0]
    out[1] = m * jacp[2]
    out[2] = ang[1]
    return out


def foot_jacobian(model: mujoco.MjModel, data: mujoco.MjData, body: int) -> np.ndarray:
    """Planar Jacobian (3 x nv) of a foot body frame: rows x, z, pitch."""
    jacp = np.empty((3, model.nv))
    jacr = np.empty((3, model.nv))
    mujoco.mj_jacBody(model, data, jacp, jacr, body)
    return np.stack([jacp[0], jacp[2], jacr[1]])


class KinematicsScratch:
    """Evaluates A and the support Jacobian at perturbed configurations for the biases."""

    def __init__(self, model: mujoco.MjModel, support_bodies: tuple[int, ...]):
        self.model = model
        self.data = mujoco.MjData(model)
        self.support_bodies = support_bodies

    def _at(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m, d = self.model, self.data
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        A = centroidal_momentum_matrix(m, d)
        Js = (
            np.concatenate([foot_jacobian(m, d, b) for b in self.support_bodies])
            if self.support_bodies
            else np.zeros((0, m.nv))
        )
        return A, Js

    def biases(self, qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Adot qd, Jsdot qd) by central differences along qd.

        Valid because every joint here is a hinge or slide (nq == nv, q + eps qd is a
        legal configuration); a free or ball joint would need mj_integratePos.
        """
        Ap, Jp = self._at(qpos + FD_EPS_S * qvel)
        Am, Jm = self._at(qpos - FD_EPS_S * qvel)
        scale = 1.0 / (2.0 * FD_EPS_S)
        return (Ap - Am) @ qvel * scale, (Jp - Jm) @ qvel * scale
