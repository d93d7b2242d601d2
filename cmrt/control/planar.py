"""Vectorised planar rigid-body quantities from MuJoCo's com-based spatial fields.

Every function works on arrays with a leading batch axis (n simulations) bound from a
``mujoco.batch.Batch`` (``cdof``, ``cdof_dot``, ``cvel``, ``cinert``, ``xpos``,
``subtree_com``, ``M``), so a whole CMA-ES generation is controlled with a few numpy
calls per step instead of a Python loop over simulations.

MuJoCo's "c-frame" is centred on the subtree CoM of the tree's root body, i.e. on the
whole character's CoM ``c``: spatial momentum there *is* the centroidal momentum. In the
sagittal plane a spatial motion reduces to the twist (omega_y, v_x, v_z) and a spatial
force to (n_y, f_x, f_z); a body's com-based inertia (``cinert``: I about c, m r, m)
then maps its twist to (H_y, L_x, L_z) with the 3x3 matrix

    [[I_yy,  m r_z, -m r_x],
     [m r_z, m,      0    ],
     [-m r_x, 0,     m    ]].

Momentum rate at zero joint acceleration (the bias ``a`` of ``A qdd + a``), with c held
fixed in space for the instant: sum_b P_b abias_b + v_b x* (P_b v_b), where
``abias_b = sum_{dofs j above b} cdof_dot_j qd_j``. The total CoM's own motion adds
nothing to the pitch row since d/dt (c x L) = c' x m c' = 0. Checked against
``subtree_linvel``/``subtree_angmom`` and finite differences in tests/control.
"""

from __future__ import annotations

import mujoco
import numpy as np

# Planar components of MuJoCo's 6-vectors [ang(3), lin(3)]: omega_y, v_x, v_z.
PLANAR = np.array([1, 3, 5])


class PlanarKinematics:
    """Constant index structure of the model for the vectorised formulas."""

    def __init__(self, model: mujoco.MjModel):
        self.model = model
        nb, nv = model.nbody, model.nv
        ancestor = np.zeros((nb, nb), dtype=bool)  # ancestor[a, b]: a is b or above b
        for b in range(nb):
            a = b
            while True:
                ancestor[a, b] = True
                if a == 0:
                    break
                a = model.body_parentid[a]
        # chain[b, j]: dof j moves body b
        self.chain = ancestor[model.dof_bodyid, :].T.astype(float)  # (nb, nv)
        rows = np.repeat(np.arange(nv), model.M_rownnz)
        self.m_rows, self.m_cols = rows, model.M_colind.copy()
        self.mass = float(model.body_subtreemass[1])

    # --- building blocks --------------------------------------------------------
    @staticmethod
    def planar(x6: np.ndarray) -> np.ndarray:
        return x6[..., PLANAR]

    @staticmethod
    def body_inertia(cinert: np.ndarray) -> np.ndarray:
        """(n, nb, 3, 3) planar com-based inertia mapping (w, vx, vz) -> (H_y, L_x, L_z)."""
        P = np.zeros(cinert.shape[:-1] + (3, 3))
        P[..., 0, 0] = cinert[..., 1]  # I_yy about c
        P[..., 0, 1] = P[..., 1, 0] = cinert[..., 8]  # m r_z
        P[..., 0, 2] = P[..., 2, 0] = -cinert[..., 6]  # -m r_x
        P[..., 1, 1] = P[..., 2, 2] = cinert[..., 9]  # m
        return P

    @staticmethod
    def cross_force(v: np.ndarray, f: np.ndarray) -> np.ndarray:
        """Planar v x* f for twists v = (w, vx, vz) and wrenches f = (n, fx, fz)."""
        out = np.empty(np.broadcast_shapes(v.shape, f.shape))
        out[..., 0] = v[..., 2] * f[..., 1] - v[..., 1] * f[..., 2]
        out[..., 1] = v[..., 0] * f[..., 2]
        out[..., 2] = -v[..., 0] * f[..., 1]
        return out

    def dense_mass_matrix(self, m_sparse: np.ndarray) -> np.ndarray:
        nv = self.model.nv
        out = np.zeros(m_sparse.shape[:-1] + (nv, nv))
        out[..., self.m_rows, self.m_cols] = m_sparse
        out[..., self.m_cols, self.m_rows] = m_sparse
        return out

    # --- the quantities the controller needs -------------------------------------
    def centroidal(self, cdof, cdof_dot, cvel, cinert, qvel):
        """A (n, 3, nv) with rows [L_x, L_z, H_y], and its bias a (n, 3)."""
        n, nv = qvel.shape
        s = self.planar(cdof)  # (n, nv, 3)
        P = self.body_inertia(cinert)  # (n, nb, 3, 3)
        # A[:, :, j] = sum_b chain[b, j] P_b s_j
        Pc = (self.chain.T @ P.reshape(n, -1, 9)).reshape(n, nv, 3, 3)
        A_hl = (Pc @ s[..., None])[..., 0]  # (n, nv, 3): (H, Lx, Lz) per dof
        v = self.planar(cvel)  # (n, nb, 3)
        abias = self.chain @ (self.planar(cdof_dot) * qvel[..., None])  # (n, nb, 3)
        Pv = (P @ v[..., None])[..., 0]
        hdot = (P @ abias[..., None])[..., 0].sum(axis=1) + self.cross_force(v, Pv).sum(axis=1)
        order = [1, 2, 0]  # (H, Lx, Lz) -> (Lx, Lz, H)
        return np.swapaxes(A_hl[..., order], 1, 2), hdot[:, order]

    def point_jacobians(self, cdof, points, com, bodies):
        """(n, k, 2, nv) Jacobians of the x, z velocity of k points, point i fixed to ``bodies[i]``."""
        s = self.planar(cdof)[:, None] * self.chain[bodies][None, :, :, None]  # (n, k, nv, 3)
        r = points - com[:, None]  # (n, k, 3)
        J = np.empty(s.shape[:2] + (2, s.shape[2]))
        J[:, :, 0] = s[..., 1] + s[..., 0] * r[..., 2:3]
        J[:, :, 1] = s[..., 2] - s[..., 0] * r[..., 0:1]
        return J

    def frame_jacobians_and_biases(self, cdof, cdof_dot, cvel, qvel, points, com, bodies):
        """(n, k, 3, nv) Jacobians of (x, z, pitch) of k body frames at ``points``, and Jdot qd (n, k, 3)."""
        chain = self.chain[bodies]  # (k, nv)
        n, k = points.shape[:2]
        J = np.empty((n, k, 3, qvel.shape[1]))
        J[:, :, :2] = self.point_jacobians(cdof, points, com, bodies)
        J[:, :, 2] = self.planar(cdof)[:, None, :, 0] * chain
        alpha_a = chain @ (self.planar(cdof_dot) * qvel[..., None])  # (n, k, 3) spatial bias acc
        v = self.planar(cvel[:, bodies])  # (n, k, 3)
        r = points - com[:, None]
        w = v[..., 0]
        vpx = v[..., 1] + w * r[..., 2]
        vpz = v[..., 2] - w * r[..., 0]
        bias = np.empty((n, k, 3))
        bias[..., 0] = alpha_a[..., 1] + alpha_a[..., 0] * r[..., 2] + w * vpz
        bias[..., 1] = alpha_a[..., 2] - alpha_a[..., 0] * r[..., 0] - w * vpx
        bias[..., 2] = alpha_a[..., 0]
        return J, bias
