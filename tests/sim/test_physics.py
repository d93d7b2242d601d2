"""Measured CoP and ground forces against MuJoCo's contact forces and whole-body dynamics."""

import mujoco
import numpy as np

from cmrt.body.character import character
from cmrt.control.momentum import KinematicsScratch, centroidal_momentum_matrix
from cmrt.motion.taskfile import load_task
from cmrt.sim.simulate import simulate


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
    flat = np.all(traj.point_lift_m < 1e-3, axis=1) & np.isfinite(traj.cop_x_m)
    assert flat.all()
    inside = (traj.cop_x_m >= traj.support_lo_x_m - 1e-9) & (traj.cop_x_m <= traj.support_hi_x_m + 1e-9)
    assert inside[flat].all()


def test_planned_ground_force_is_feasible_and_is_what_mujoco_applies():
    """The torques ask the ground for exactly the wrench the plan needs: at states along a bend, the
    plan's vertical force and CoP equal the contact forces MuJoCo then applies, the CoP is inside the
    feet, every heel/toe point is pressed and the friction cone holds."""
    from cmrt.control import ControllerConfig, MomentumBalanceController
    from cmrt.sim.simulate import CONTROL_FIELDS, _in_contact

    ch = character()
    m = ch.model
    task = load_task("bend").with_speed(0.8)
    # the states of a clip planned as this test plans (no feedback delay: the test calls the controller with the
    # present CoM); from a delayed clip's states the undelayed plan is far from what the contacts carry now, and
    # MuJoCo's soft contacts then regularise up to 2.9 % of body weight in the first step
    config = ControllerConfig(feedback_delay_s=0.0)
    traj = simulate(task, config=config)
    controller = MomentumBalanceController(ch, config)
    q_ref, qd_ref, qdd_ref = task.reference(traj.time_s)
    points = np.array(ch.foot_point_geoms)
    d = mujoco.MjData(m)
    for k in range(400, 1400, 40):
        d.qpos[:], d.qvel[:] = traj.qpos[k], traj.qvel[k]
        mujoco.mj_forward(m, d)
        f = {name: getattr(d, name)[None].copy() for name in CONTROL_FIELDS}
        xs = d.geom_xpos[points, 0]
        center = np.array([0.5 * (xs.min() + xs.max())])
        out = controller.torques(f, q_ref[k], qd_ref[k], qdd_ref[k], center, np.zeros(1), center,
                                 _in_contact(d.geom_xpos[None], points))
        fx, fz = out.ground_force_n[0]
        cop = out.cop_x_m[0]
        assert np.all(out.foot_state == 0)  # both feet flat
        share_toe = (cop - xs.min()) / (xs.max() - xs.min())
        # every point keeps its floor: 40 N, or half an equal share where the load is too low for that
        assert min(share_toe, 1 - share_toe) * fz / 2 >= min(config.min_point_force_n, fz / 8) - 1e-6
        assert abs(fx) <= config.friction_coef * fz + 1e-6
        d.ctrl[:] = out.torque_nm[0]
        mujoco.mj_forward(m, d)
        touch = d.sensordata[:4]
        # MuJoCo's soft contacts regularise the constraint force: agreement to 1 % of body weight
        assert abs(touch.sum() - fz) < 0.01 * ch.mass_kg * 9.81
        assert abs((touch * xs).sum() / touch.sum() - cop) < 1e-3
