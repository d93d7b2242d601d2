"""Centroidal momentum matrix A and its bias a = Adot qd, from MuJoCo: the reference the compiled kernel is
checked against.

The spatial rows are [L_x, L_y, L_z, H_x, H_y, H_z]: linear momentum (kg m/s) and angular momentum about the CoM
(kg m^2/s), so that momentum = A qd and its rate = A qdd + a. A body moves in some of them
(``Character.momentum_rows``): the planar body in [L_x, L_z, H_y] (the default ``rows``), the 3D body in all six.
MuJoCo has no built-in for the bias; we take a central finite difference of A along qd (two extra kinematics
passes on a scratch MjData, stepping the configuration with ``mj_integratePos`` so a free joint's quaternion stays
one). Error O(eps^2) with eps = 1e-5 s: ~1e-9 relative, checked against MuJoCo in tests/sim/test_physics.py.
"""

from __future__ import annotations

import mujoco
import numpy as np

from cmrt.body.character import PLANAR_ROWS

FD_EPS_S = 1e-5


def centroidal_momentum_matrix(model: mujoco.MjModel, data: mujoco.MjData, out: np.ndarray | None = None,
                               rows: tuple[int, ...] = PLANAR_ROWS) -> np.ndarray:
    """A (len(rows) x nv) at the current kinematics (needs mj_kinematics + mj_comPos done)."""
    nv = model.nv
    spatial = np.empty((6, nv))
    mujoco.mj_jacSubtreeCom(model, data, spatial[:3], 1)
    spatial[:3] *= model.body_subtreemass[1]
    mujoco.mj_angmomMat(model, data, spatial[3:], 1)
    out = np.empty((len(rows), nv)) if out is None else out
    out[:] = spatial[list(rows)]
    return out


def foot_jacobian(model: mujoco.MjModel, data: mujoco.MjData, body: int,
                  rows: tuple[int, ...] = PLANAR_ROWS) -> np.ndarray:
    """Jacobian (len(rows) x nv) of a foot body frame's [linear, angular] velocity (planar: x, z, pitch)."""
    jac = np.empty((6, model.nv))
    mujoco.mj_jacBody(model, data, jac[:3], jac[3:], body)
    return jac[list(rows)]


class KinematicsScratch:
    """Evaluates A and the support Jacobian at perturbed configurations for the biases."""

    def __init__(self, model: mujoco.MjModel, support_bodies: tuple[int, ...], rows: tuple[int, ...] = PLANAR_ROWS):
        self.model = model
        self.data = mujoco.MjData(model)
        self.support_bodies = support_bodies
        self.rows = rows

    def _at(self, qpos: np.ndarray, qvel: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        m, d = self.model, self.data
        d.qpos[:] = qpos
        mujoco.mj_integratePos(m, d.qpos, qvel, dt)  # hinges and slides: qpos + dt qvel, to the bit
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        A = centroidal_momentum_matrix(m, d, rows=self.rows)
        Js = (
            np.concatenate([foot_jacobian(m, d, b, self.rows) for b in self.support_bodies])
            if self.support_bodies
            else np.zeros((0, m.nv))
        )
        return A, Js

    def biases(self, qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Adot qd, Jsdot qd) by central differences along qd."""
        Ap, Jp = self._at(qpos, qvel, FD_EPS_S)
        Am, Jm = self._at(qpos, qvel, -FD_EPS_S)
        scale = 1.0 / (2.0 * FD_EPS_S)
        return (Ap - Am) @ qvel * scale, (Jp - Jm) @ qvel * scale
