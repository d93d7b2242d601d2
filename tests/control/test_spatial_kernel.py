"""The 3D step's compiled parts (cmrt.control.spatial_kernel) against MuJoCo's own functions, on a moving 3D body:
the contact points' Jacobians (``mj_jac`` at each sphere's lowest point), the joint-space inertia (``mj_fullM``),
a carried mass's dynamics (``mj_jac``/``mj_jacDot`` averaged over the hands), the swing foot's way back to level
(``mju_subQuat``), and the delayed feedback's ring buffer (the oldest of the last delay + 1 steps)."""

import mujoco
import numpy as np

from cmrt.body.character import GRAVITY_M_S2, character
from cmrt.control import spatial_kernel as sk
from cmrt.control.spatial import SpatialController
from cmrt.sim.spatial import BODY, stand_pose_qpos


def _moving():
    """The 3D body in a random pose near standing, moving, forward-computed."""
    ch = character(BODY)
    m = ch.model
    d = mujoco.MjData(m)
    rng = np.random.default_rng(11)
    d.qpos[:] = stand_pose_qpos()
    d.qpos[7:] += 0.2 * rng.standard_normal(m.nq - 7)
    d.qvel[:] = 0.5 * rng.standard_normal(m.nv)
    mujoco.mj_forward(m, d)
    return ch, m, d, SpatialController(ch, d.qpos.copy())


def test_the_point_jacobians_are_mujocos():
    ch, m, d, ctl = _moving()
    body = ctl._body
    J = sk._point_jacobians(d.cdof, body[0], body[9], body[10], body[11], d.geom_xpos, d.subtree_com[1].copy())
    for p, g in enumerate(ch.foot_point_geoms):
        lowest = d.geom_xpos[g] - [0.0, 0.0, m.geom_size[g, 0]]
        expected = np.zeros((3, m.nv))
        mujoco.mj_jac(m, d, expected, None, lowest, m.geom_bodyid[g])
        np.testing.assert_allclose(J[3 * p:3 * p + 3], expected, rtol=0, atol=1e-12)


def test_the_inertia_is_mujocos_and_a_carried_mass_adds_its_own():
    ch, m, d, ctl = _moving()
    body = ctl._body
    M, bias = sk._dynamics(d.M, body[1], body[2], d.qfrc_bias, np.zeros(m.nv), m.nv)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    np.testing.assert_allclose(M, full, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(bias, d.qfrc_bias)
    hands = (m.body("forearm_r").id, m.body("forearm_l").id)
    point = 0.5 * (d.xpos[hands[0]] + d.xpos[hands[1]]) + [0.1, 0.0, 0.0]
    targets = np.zeros(sk.N_TARGETS)
    targets[sk.T_HELD], targets[sk.T_HELD_AT:sk.T_HELD_AT + 3] = 7.0, point
    sk._holding(d.cdof, d.cdof_dot, d.cvel, d.qvel.copy(), body[0], np.array(hands), targets,
                d.subtree_com[1].copy(), ctl._gains, M, bias)
    jac, rate = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    one, one_rate = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for h in hands:  # the mean over the hands of the point's Jacobian and its rate, MuJoCo's
        mujoco.mj_jac(m, d, one, None, point, h)
        mujoco.mj_jacDot(m, d, one_rate, None, point, h)
        jac += one / 2
        rate += one_rate / 2
    np.testing.assert_allclose(M, full + 7.0 * jac.T @ jac, rtol=0, atol=1e-10)
    expected = d.qfrc_bias + 7.0 * jac.T @ (rate @ d.qvel + [0.0, 0.0, GRAVITY_M_S2])
    np.testing.assert_allclose(bias, expected, rtol=0, atol=1e-9)


def test_the_swing_foot_is_sent_back_to_level_by_mujocos_rotation():
    """With no path error and no motion asked, the swing objective's linear term is the foot frame's Jacobian
    times the stiffness times MuJoCo's rotation back to level (``mju_subQuat``), less its damping and rate."""
    ch, m, d, ctl = _moving()
    foot = ch.foot_bodies[0]
    H, f = np.zeros((m.nv, m.nv)), np.zeros(m.nv)
    targets = np.zeros(sk.N_TARGETS)
    targets[sk.T_SWING_POS:sk.T_SWING_POS + 3] = d.xpos[foot]
    sk._swing_objective(d.cdof, d.cdof_dot, d.cvel, d.qvel.copy(), ctl._body[0], foot, d.xpos, d.xquat,
                        d.subtree_com[1].copy(), targets, ctl._gains, H, f)
    jac, jdot = np.zeros((6, m.nv)), np.zeros((6, m.nv))
    mujoco.mj_jacBody(m, d, jac[:3], jac[3:], foot)
    mujoco.mj_jacDot(m, d, jdot[:3], jdot[3:], d.xpos[foot], foot)
    local, level = np.zeros(3), np.zeros(3)
    mujoco.mju_subQuat(local, np.array([1.0, 0.0, 0.0, 0.0]), d.xquat[foot])
    mujoco.mju_rotVecQuat(level, local, d.xquat[foot])
    c = ctl.config
    vel = jac @ d.qvel
    want = np.concatenate([-c.swing_d * vel[:3], c.swing_k * level - c.swing_d * vel[3:]]) - jdot @ d.qvel
    np.testing.assert_allclose(f, -2.0 * c.swing_weight * jac.T @ want, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(H, 2.0 * c.swing_weight * jac.T @ jac, rtol=1e-9, atol=1e-9)


def test_the_feedback_buffer_keeps_the_last_delay_plus_one_coms():
    """The delayed feedback's ring buffer (here three deep) holds the CoMs of the last three control steps - the
    one fed back is the oldest of them - however many steps were planned: the body moved 1 cm each of six steps."""
    ch, m, d, ctl = _moving()
    ctl._history, ctl._count = np.zeros((3, 6)), np.zeros(1, np.int64)
    coms = []
    for _ in range(6):
        d.qpos[0] += 0.01
        mujoco.mj_forward(m, d)
        coms.append(d.subtree_com[1, 0])
        ctl.plan(d, np.ones(len(ch.foot_point_geoms), bool))
    assert ctl._count[0] == 6
    oldest = ctl._count[0] % 3  # the slot the next step writes: the oldest kept
    np.testing.assert_array_equal(np.roll(ctl._history[:, 0], -oldest), coms[-3:])
