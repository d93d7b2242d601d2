"""The controller's momentum quantities against MuJoCo's own."""

import mujoco
import numpy as np

from cmrt.control.momentum import KinematicsScratch, centroidal_momentum_matrix, foot_jacobian


def momentum(m, d, q, qd):
    d.qpos[:], d.qvel[:] = q, qd
    mujoco.mj_forward(m, d)
    return centroidal_momentum_matrix(m, d) @ qd


def test_momentum_matches_mujoco_subtree(state):
    ch, m, d, _ = state
    A = centroidal_momentum_matrix(m, d)
    mujoco.mj_subtreeVel(m, d)
    mass = m.body_subtreemass[1]
    expected = np.array([mass * d.subtree_linvel[1, 0], mass * d.subtree_linvel[1, 2], d.subtree_angmom[1, 1]])
    np.testing.assert_allclose(A @ d.qvel, expected, rtol=0, atol=1e-9)


def test_momentum_rate_bias_matches_time_derivative(state):
    """A qdd + a equals d/dt (A qd) along a trajectory with acceleration qdd."""
    ch, m, d, rng = state
    q, qd = d.qpos.copy(), d.qvel.copy()
    qdd = rng.normal(scale=5.0, size=m.nv)
    A = centroidal_momentum_matrix(m, d)
    a, jsdot = KinematicsScratch(m, ch.foot_bodies).biases(q, qd)
    h = 1e-5
    scratch = mujoco.MjData(m)
    plus = momentum(m, scratch, q + h * qd + 0.5 * h * h * qdd, qd + h * qdd)
    minus = momentum(m, scratch, q - h * qd + 0.5 * h * h * qdd, qd - h * qdd)
    np.testing.assert_allclose(A @ qdd + a, (plus - minus) / (2 * h), rtol=1e-6, atol=1e-6)

    # the support-foot bias the same way: d/dt (Js qd) = Js qdd + Jsdot qd
    def foot_vel(qq, vv):
        scratch.qpos[:], scratch.qvel[:] = qq, vv
        mujoco.mj_forward(m, scratch)
        return np.concatenate([foot_jacobian(m, scratch, b) @ vv for b in ch.foot_bodies])

    Js = np.concatenate([foot_jacobian(m, d, b) for b in ch.foot_bodies])
    fd = (
        foot_vel(q + h * qd + 0.5 * h * h * qdd, qd + h * qdd) - foot_vel(q - h * qd + 0.5 * h * h * qdd, qd - h * qdd)
    ) / (2 * h)
    np.testing.assert_allclose(Js @ qdd + jsdot, fd, rtol=1e-6, atol=1e-6)
