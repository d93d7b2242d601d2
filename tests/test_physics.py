"""Measured CoP and ground forces against MuJoCo's whole-body dynamics."""

import mujoco
import numpy as np

from cmrt.character import character
from cmrt.control.momentum import KinematicsScratch, centroidal_momentum_matrix
from cmrt.simulate import _contact_summary, simulate
from cmrt.task import load_task


def test_cop_and_ground_force_match_momentum_rate():
    """Sum of contact forces = Ldot - m g and CoP = c_x - (Hdot + c_z F_x) / F_z (mid fast bend)."""
    ch = character()
    m = ch.model
    task = load_task("bend").with_speed(0.8)
    traj = simulate(task)
    d = mujoco.MjData(m)
    scratch = KinematicsScratch(m, ch.foot_bodies)
    checked = 0
    for k in range(450, 1000, 50):  # preparation end, the bend and decay
        d.qpos[:], d.qvel[:], d.ctrl[:] = traj.qpos[k], traj.qvel[k], traj.ctrl_nm[k]
        mujoco.mj_forward(m, d)
        A = centroidal_momentum_matrix(m, d)
        a, _ = scratch.biases(d.qpos.copy(), d.qvel.copy())
        ldot_x, ldot_z, hdot = A @ d.qacc + a
        force = np.zeros(3)
        f6 = np.zeros(6)
        for i in range(d.ncon):
            mujoco.mj_contactForce(m, d, i, f6)
            force += d.contact[i].frame.reshape(3, 3).T @ f6[:3]
        mass = ch.mass_kg
        np.testing.assert_allclose([force[0], force[2]], [ldot_x, ldot_z + mass * 9.81], rtol=1e-6, atol=1e-6)
        cop, fz_r, fz_l, other = _contact_summary(ch, m, d, f6)
        com = d.subtree_com[1]
        cop_from_momentum = com[0] - (hdot + com[2] * force[0]) / force[2]
        assert abs(cop - cop_from_momentum) < 2e-4
        assert abs(fz_r + fz_l - force[2]) < 1e-6 and not other
        checked += 1
    assert checked >= 10


def test_cop_stays_inside_support_while_feet_are_flat():
    task = load_task("bend").with_speed(1.2)
    traj = simulate(task)
    flat = np.all(traj.point_lift_m < 1e-3, axis=1)
    assert flat.all()
    inside = (traj.cop_x_m >= traj.support_lo_x_m - 1e-9) & (traj.cop_x_m <= traj.support_hi_x_m + 1e-9)
    assert inside[flat].all()
