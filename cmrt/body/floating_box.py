"""A box floating on water with the character on its deck (Yu's floating box, thesis figs. 4.5 and 4.8).

Unlike a slope or a shaking plane, this support moves because of what the character does on it: it is not a
prescribed trajectory but three more degrees of freedom, the deck centre's x, z (m, world, from where the box
floats at rest with the character on it) and its tilt theta about +y (rad; positive takes the deck's +x end
down, as ``cmrt.body.surface``). The character is still simulated in the deck's frame (``Support.field``'s
terms, from this box's motion); the box is integrated beside MuJoCo, one physics step at a time:

* **the water** is a spring-damper on the deck centre: a vertical buoyancy stiffness ``box_stiffness_n_m``
  (rho g times the waterline area: 1 m x 1 m of deck is 9.81 kN/m), the righting moment of that stiffness spread
  over the deck's width (k W^2 / 12), water drag horizontally, and a damping ratio ``box_damping_ratio`` of the
  critical damping of the loaded box. Buoyancy carries box and character at rest;
* **the box** is a rigid body of ``box_mass_kg``, its mass lumped at the deck's centre (a raft: the deck centre
  is the support frame's origin), inertia of a W x H block;
* **the character's load** on it is the contact force on the humanoid, read from MuJoCo's own constraint
  force on the root's three coordinates (``qfrc_constraint``: the total contact force and its moment about the
  root), turned around.

**Why the coupling is not simply explicit.** That load is known only after MuJoCo's step, so the box takes the
one of the step before. A lag on its own is unstable when the box is not much heavier than its load: the
character's inertia acts as an added mass (partitioned fluid-structure coupling's classic failure). The box's
step therefore moves the character's rigid-body inertia about the deck centre, M_c (3 x 3), to the left side:

    (M_box + M_c) a_k = W_water(k) + W_char(k-1) + M_c a_(k-1)

exact when the character moves rigidly with the deck (its load then changes by -M_c (a_k - a_(k-1))), and the
lag's error is only the character's own motion's change over one step. ``tests/body/test_floating_box.py`` checks
the whole scheme against a real MuJoCo box body carrying a block, with the box lighter than the block.
"""

from __future__ import annotations

import math

import numpy as np

from cmrt.body.character import GRAVITY_M_S2

BOX_WIDTH_M = 1.0  # the deck's length along x: the feet stand on its middle
BOX_HEIGHT_M = 0.4  # for the box's inertia and the pictures


def contact_wrench(qfrc_root: np.ndarray, anchor_xz: np.ndarray) -> np.ndarray:
    """(k, 3): the contact force (x, z; N) on a tree whose root is slide x, slide z, hinge y (MuJoCo's
    ``qfrc_constraint`` on those three coordinates) and its moment (N m) about the support's origin: the hinge's
    is about its anchor ``anchor_xz`` (k, 2), r x F moves it."""
    fx, fz, m_anchor = qfrc_root[:, 0], qfrc_root[:, 1], qfrc_root[:, 2]
    return np.stack([fx, fz, m_anchor + anchor_xz[:, 1] * fx - anchor_xz[:, 0] * fz], axis=1)


def _rotate(theta: np.ndarray, x: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Support axes -> world axes (a turn of theta about +y)."""
    c, s = np.cos(theta), np.sin(theta)
    return c * x + s * z, -s * x + c * z


def rigid_inertia(mass_kg: np.ndarray, com_xz: np.ndarray, inertia_com: np.ndarray) -> np.ndarray:
    """(k, 3, 3): the planar spatial inertia about the origin of a rigid body of ``mass_kg`` with its CoM at
    ``com_xz`` (k, 2) and moment of inertia ``inertia_com`` about it: the wrench (F_x, F_z, M_y) that moves it
    with the origin's acceleration (a_x, a_z) and an angular acceleration alpha (a point at r then accelerates
    by a + alpha (r_z, -r_x))."""
    m, cx, cz = mass_kg, com_xz[:, 0], com_xz[:, 1]
    out = np.zeros((m.size, 3, 3))
    out[:, 0, 0] = out[:, 1, 1] = m
    out[:, 0, 2] = out[:, 2, 0] = m * cz
    out[:, 1, 2] = out[:, 2, 1] = -m * cx
    out[:, 2, 2] = inertia_com + m * (cx * cx + cz * cz)
    return out


class FloatingBox:
    """The box's state for ``n`` simulations: deck-centre position ``q`` (x, z, theta), velocity ``v`` and the
    acceleration ``a`` of the step being taken, each (n, 3), world axes."""

    def __init__(self, n: int, mass_kg: float, stiffness_n_m: float, damping_ratio: float, carried_kg: float,
                 carried_inertia_kg_m2: float, timestep_s: float):
        """``carried_*``: the character's mass and its moment of inertia about the deck centre standing (for the
        critical damping of the loaded box)."""
        self.dt = timestep_s
        self.q, self.v, self.a = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
        inertia = mass_kg * (BOX_WIDTH_M ** 2 + BOX_HEIGHT_M ** 2) / 12.0
        self.box_inertia = np.diag([mass_kg, mass_kg, inertia])
        k_pitch = stiffness_n_m * BOX_WIDTH_M ** 2 / 12.0  # buoyancy spread over the deck: its righting moment
        self.stiffness = np.array([0.0, stiffness_n_m, k_pitch])  # no spring sideways: the box drifts, dragged
        c_heave = 2.0 * damping_ratio * math.sqrt(stiffness_n_m * (mass_kg + carried_kg))
        c_pitch = 2.0 * damping_ratio * math.sqrt(k_pitch * (inertia + carried_inertia_kg_m2))
        self.damping = np.array([c_heave, c_heave, c_pitch])
        self.carried_weight_n = carried_kg * GRAVITY_M_S2  # buoyancy beyond the box's own weight, at rest

    def advance(self, rows: np.ndarray, wrench_s: np.ndarray, mass_kg: np.ndarray, com_s: np.ndarray,
                inertia_com: np.ndarray) -> None:
        """One physics step of rows ``rows``: the acceleration of the step just taken moves the box, then the
        next one is solved from the water and the character's load. ``wrench_s`` (k, 3): the contact force on the
        character in the step just taken (support axes) and its moment about the deck centre; ``mass_kg``,
        ``com_s`` (k, 2; support axes), ``inertia_com``: the character as a rigid body (its added mass)."""
        q, v, a_old = self.q[rows], self.v[rows], self.a[rows]
        v = v + self.dt * a_old  # semi-implicit Euler, as MuJoCo's own integrator
        q = q + self.dt * v
        theta = q[:, 2]
        fx, fz = _rotate(theta, wrench_s[:, 0], wrench_s[:, 1])
        load = -np.stack([fx, fz, wrench_s[:, 2]], axis=1)  # the character pushes the deck as the deck pushes it
        water = -self.stiffness * q - self.damping * v
        water[:, 1] += self.carried_weight_n  # buoyancy (the box's own weight and its share cancel)
        cx, cz = _rotate(theta, com_s[:, 0], com_s[:, 1])
        added = rigid_inertia(mass_kg, np.stack([cx, cz], axis=1), inertia_com)
        rhs = water + load + np.einsum("kij,kj->ki", added, a_old)
        self.a[rows] = np.linalg.solve(self.box_inertia + added, rhs[..., None])[..., 0]
        self.q[rows], self.v[rows] = q, v

    def hold(self, rows: np.ndarray) -> None:
        """Stop rows ``rows``'s boxes where they are (a topple played out for pictures only)."""
        self.v[rows] = 0.0
        self.a[rows] = 0.0

    def frame(self, rows) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """theta, omega, alpha (k,) and the deck centre's acceleration (k, 2): the support frame's motion."""
        return self.q[rows, 2], self.v[rows, 2], self.a[rows, 2], self.a[rows, :2]
