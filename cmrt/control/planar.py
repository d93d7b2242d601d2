"""The model's constant index structure, and centroidal momentum from MuJoCo's com-based fields.

MuJoCo's "c-frame" is centred on the subtree CoM of the tree's root body, i.e. on the
whole character's CoM: spatial momentum there *is* the centroidal momentum. In the
sagittal plane a spatial motion reduces to the twist (omega_y, v_x, v_z) and a body's
com-based inertia (``cinert``: I about c, m r, m) maps it to (H_y, L_x, L_z) with

    [[I_yy,  m r_z, -m r_x],
     [m r_z, m,      0    ],
     [-m r_x, 0,     m    ]].

The controller's per-step arithmetic (momentum matrix, its bias, foot Jacobians) is
compiled in ``cmrt.control.kernel``; this module holds what it needs from the model and
the vectorised momentum the balance monitor reads for every simulation.
"""

from __future__ import annotations

import mujoco
import numpy as np

# Planar components of MuJoCo's 6-vectors [ang(3), lin(3)]: omega_y, v_x, v_z.
PLANAR = np.array([1, 3, 5])


class PlanarKinematics:
    """Constant index structure of the model (the humanoid: props come after it in a task model)."""

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
        self.chain = ancestor[model.dof_bodyid, :].T.copy()  # (nb, nv): dof j moves body b
        rows = np.repeat(np.arange(nv), model.M_rownnz)  # the sparse mass matrix's lower triangle, CSR
        self.m_rows, self.m_cols = rows, model.M_colind.copy()
        self.mass = float(model.body_subtreemass[1])

    @staticmethod
    def body_inertia(cinert: np.ndarray) -> np.ndarray:
        """(n, nb, 3, 3) planar com-based inertia mapping (w, vx, vz) -> (H_y, L_x, L_z)."""
        P = np.zeros(cinert.shape[:-1] + (3, 3))
        P[..., 0, 0] = cinert[..., 1]  # I_yy about c
        P[..., 0, 1] = P[..., 1, 0] = cinert[..., 8]  # m r_z
        P[..., 0, 2] = P[..., 2, 0] = -cinert[..., 6]  # -m r_x
        P[..., 1, 1] = P[..., 2, 2] = cinert[..., 9]  # m
        return P

    def momentum(self, cinert: np.ndarray, cvel: np.ndarray) -> np.ndarray:
        """(n, 3) centroidal momentum (H_y, L_x, L_z): the sum of the bodies' P_b v_b."""
        return (self.body_inertia(cinert) @ cvel[..., PLANAR][..., None])[..., 0].sum(axis=1)

    @staticmethod
    def linear_momentum(cinert: np.ndarray, cvel: np.ndarray) -> np.ndarray:
        """(n, 2) linear momentum (L_x, L_z): the rows of ``momentum`` the balance monitor needs, cheaply."""
        w, vx, vz = cvel[..., 1], cvel[..., 3], cvel[..., 5]
        m, mrx, mrz = cinert[..., 9], cinert[..., 6], cinert[..., 8]
        out = np.empty((cinert.shape[0], 2))
        out[:, 0] = (mrz * w + m * vx).sum(axis=1)
        out[:, 1] = (m * vz - mrx * w).sum(axis=1)
        return out
