"""Measured CoP and ground forces against MuJoCo's contact forces and whole-body dynamics."""

import mujoco
import numpy as np

from cmrt.character import character
from cmrt.control.momentum import KinematicsScratch, centroidal_momentum_matrix
from cmrt.simulate import simulate
from cmrt.task import load_task


def contact_forces(m, d):
    """World-frame force and position of every contact, from mj_contactForce."""
    out = []
    f6 = np.zeros(6)
    for i in range(d.ncon):
        mujoco.mj_contactForce(m, d, i, f6)
        out.append((d.contact[i].frame.reshape(3, 3).T @ f6[:3], d.contact[i].pos.copy()))
    return out


def test_cop_and_ground_force_match_contacts_and_momentum_rate():
    """Over a bend: recorded CoP = CoP of the contact forces = CoP implied by the momentum rate,
    and the sum of contact forces = Ldot - m g."""
    ch = character()
    m = ch.model
    task = load_task("bend").with_speed(0.8)
    traj = simulate(task)
    d = mujoco.MjData(m)
    scratch = KinematicsScratch(m, ch.foot_bodies)
    checked = 0
    for k in range(450, 1000, 50):  # end of preparation, the bend, the decay
        d.qpos[:], d.qvel[:], d.ctrl[:] = traj.qpos[k], traj.qvel[k], traj.ctrl_nm[k]
        mujoco.mj_forward(m, d)
        A = centroidal_momentum_matrix(m, d)
        a, _ = scratch.biases(d.qpos.copy(), d.qvel.copy())
        ldot_x, ldot_z, hdot = A @ d.qacc + a
        contacts = contact_forces(m, d)
        force = sum(f for f, _ in contacts)
        np.testing.assert_allclose([force[0], force[2]], [ldot_x, ldot_z + ch.mass_kg * 9.81], rtol=1e-6, atol=1e-6)
        cop_contacts = sum(f[2] * p[0] for f, p in contacts) / force[2]
        com = d.subtree_com[1]
        cop_momentum = com[0] - (hdot + com[2] * force[0]) / force[2]
        assert abs(cop_contacts - cop_momentum) < 2e-4
        assert abs(traj.cop_x_m[k] - cop_contacts) < 1e-9  # recorded (touch sensors at heel and toe)
        np.testing.assert_allclose(traj.foot_normal_force_n[k].sum(), force[2], rtol=1e-6)
        checked += 1
    assert checked >= 10


def test_cop_stays_inside_support_while_feet_are_flat():
    task = load_task("bend").with_speed(1.2)
    traj = simulate(task)
    flat = np.all(traj.point_lift_m < 1e-3, axis=1)
    assert flat.all()
    inside = (traj.cop_x_m >= traj.support_lo_x_m - 1e-9) & (traj.cop_x_m <= traj.support_hi_x_m + 1e-9)
    assert inside[flat].all()
