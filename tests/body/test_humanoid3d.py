"""The 3D body (``humanoid3d.xml``): the planar body's segments with a person's out-of-plane joints, and its
centroidal momentum - the kernel's spatial formulas - against MuJoCo's own."""

import mujoco
import numpy as np
import pytest

from cmrt.body.character import BODIES, PLANAR_ROWS, SPATIAL_ROWS, character
from cmrt.control import kernel
from cmrt.control.momentum import KinematicsScratch, centroidal_momentum_matrix, foot_jacobian
from cmrt.control.planar import PlanarKinematics
from cmrt.errors import CmrtError


@pytest.fixture(scope="module")
def body3d():
    return character("humanoid3d")


def _random_state(m, rng, scale_q=0.4, scale_qd=2.0):
    """A random configuration (a unit root quaternion, joints inside their ranges) and velocity."""
    d = mujoco.MjData(m)
    d.qpos[:3] = rng.normal(scale=0.3, size=3) + [0.0, 0.0, 0.93]
    quat = rng.normal(size=4)
    d.qpos[3:7] = quat / np.linalg.norm(quat)
    for j in range(1, m.njnt):
        lo, hi = m.jnt_range[j]
        d.qpos[m.jnt_qposadr[j]] = np.clip(rng.normal(scale=scale_q), lo, hi)
    d.qvel[:] = rng.normal(scale=scale_qd, size=m.nv)
    mujoco.mj_forward(m, d)
    return d


def _planar_states(m, seed, count=20):
    """Random configurations and velocities of the planar body (its joints are hinges and slides)."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        d = mujoco.MjData(m)
        d.qpos[:] = rng.normal(scale=0.5, size=m.nq)
        d.qvel[:] = rng.normal(scale=2.0, size=m.nv)
        mujoco.mj_forward(m, d)
        yield d


def _mujoco_momentum(m, d):
    """[L, H] of the whole body about its CoM, from MuJoCo's subtree quantities."""
    mujoco.mj_subtreeVel(m, d)
    return np.concatenate([m.body_subtreemass[1] * d.subtree_linvel[1], d.subtree_angmom[1]])


def test_the_bodies_a_task_may_name():
    assert set(BODIES) == {"planar", "humanoid3d"}
    assert character() is character("planar")
    assert character().momentum_rows == PLANAR_ROWS and character("humanoid3d").momentum_rows == SPATIAL_ROWS
    with pytest.raises(CmrtError, match="unknown body 'robot'"):
        character("robot")


def test_dimensions_dofs_and_the_planar_segments(body3d):
    m, planar = body3d.model, character().model
    assert (m.nq, m.nv, m.nu) == (32, 31, 25)  # a free root (7 qpos, 6 dof) and 25 actuated hinges
    assert len(body3d.root_dofs) == 6 and len(body3d.actuated_dofs) == 25
    assert abs(body3d.mass_kg - 70.0) < 0.05
    for b in range(1, planar.nbody):  # the same segments, masses and places as the planar body's
        name = planar.body(b).name
        assert m.body(name).mass[0] == pytest.approx(planar.body(b).mass[0], abs=1e-12), name
        np.testing.assert_allclose(m.body(name).pos, planar.body(b).pos, atol=1e-12)
    for j in range(3, planar.njnt):  # every planar joint is there with its range and torque limit
        name = planar.joint(j).name
        np.testing.assert_allclose(m.joint(name).range, planar.joint(j).range, atol=1e-12)
        np.testing.assert_allclose(m.actuator(name).ctrlrange, planar.actuator(name).ctrlrange, atol=1e-12)
    per_joint = {"lumbar": 3, "neck": 2, "shoulder_r": 3, "shoulder_l": 3, "elbow_r": 1, "elbow_l": 1,
                 "hip_r": 3, "hip_l": 3, "knee_r": 1, "knee_l": 1, "ankle_r": 2, "ankle_l": 2}
    for segment_joint, count in per_joint.items():
        body = m.joint(segment_joint).bodyid[0]
        assert sum(1 for j in range(m.njnt) if m.jnt_bodyid[j] == body) == count, segment_joint


def test_feet_are_flat_boxes_on_four_points(body3d):
    m = body3d.model
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    for foot in body3d.foot_points:
        assert len(foot) == 4
        points = d.geom_xpos[list(foot)]
        assert np.ptp(points[:, 2]) < 1e-12  # one sole: all four at one height in the zero pose
        assert np.ptp(points[:, 0]) == pytest.approx(0.24) and np.ptp(points[:, 1]) == pytest.approx(0.08)
    assert m.nsensor == 8  # a touch sensor per point: the CoP from the feet's contacts alone


def test_mirrored_axes_mean_one_motion_on_both_sides(body3d):
    """A positive hip roll abducts both legs, a positive hip yaw turns both toes in."""
    m = body3d.model
    d = mujoco.MjData(m)
    for joint in ("hip_roll_r", "hip_roll_l"):
        d.qpos[m.joint(joint).qposadr[0]] = 0.3
    for joint in ("hip_yaw_r", "hip_yaw_l"):
        d.qpos[m.joint(joint).qposadr[0]] = 0.3
    mujoco.mj_forward(m, d)
    right, left = d.body("foot_r"), d.body("foot_l")
    assert right.xpos[1] < -0.09 - 0.1 and left.xpos[1] > 0.09 + 0.1  # feet out past the hips
    toe_r = d.geom("toe_in_r").xpos - d.geom("heel_in_r").xpos
    toe_l = d.geom("toe_in_l").xpos - d.geom("heel_in_l").xpos
    assert toe_r[1] > 0.0 and toe_l[1] < 0.0  # toes toward the midline


def test_joint_ranges_are_a_persons(body3d):
    """The out-of-plane ranges (AAOS normal ranges, rounded; humanoid3d.xml) in degrees: abduction, adduction..."""
    expected_deg = {"hip_roll_r": (-30, 45), "hip_yaw_r": (-45, 45), "ankle_roll_r": (-35, 15),
                    "shoulder_roll_r": (-30, 180), "shoulder_yaw_r": (-90, 70), "lumbar_roll": (-35, 35),
                    "lumbar_yaw": (-45, 45), "neck_yaw": (-60, 60)}
    for joint, (lo, hi) in expected_deg.items():
        for name in {joint, joint[:-2] + "_l" if joint.endswith("_r") else joint}:
            np.testing.assert_allclose(np.degrees(body3d.model.joint(name).range), (lo, hi), atol=0.5)


def test_centroidal_momentum_equals_mujocos_over_a_random_motion(body3d):
    """The kernel's spatial momentum matrix times qd is MuJoCo's [L, H] within 1e-9, along a random motion (the
    body falling with random torques from random states), and its bias is the rate: A qdd + a = d/dt (A qd)."""
    m = body3d.model
    chain = PlanarKinematics(m).chain
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(4):
        d = _random_state(m, rng)
        for _ in range(25):
            d.ctrl[:] = rng.uniform(-1, 1, m.nu) * m.actuator_ctrlrange[:, 1]
            mujoco.mj_step(m, d)
            mujoco.mj_forward(m, d)
            A, bias = kernel.centroidal_spatial(d.cdof, d.cdof_dot, d.cvel, d.cinert, d.qvel.copy(), chain)
            np.testing.assert_allclose(A @ d.qvel, _mujoco_momentum(m, d), rtol=0, atol=1e-9)
            np.testing.assert_allclose(A, centroidal_momentum_matrix(m, d, rows=SPATIAL_ROWS), rtol=0, atol=1e-12)
            checked += 1
        qdd = rng.normal(scale=5.0, size=m.nv)
        h = 1e-6
        plus, minus = mujoco.MjData(m), mujoco.MjData(m)
        for side, sign in ((plus, 1.0), (minus, -1.0)):
            side.qpos[:] = d.qpos
            mujoco.mj_integratePos(m, side.qpos, d.qvel + sign * 0.5 * h * qdd, sign * h)  # q +- h qd + h^2/2 qdd
            side.qvel[:] = d.qvel + sign * h * qdd
            mujoco.mj_forward(m, side)
        rate = (_mujoco_momentum(m, plus) - _mujoco_momentum(m, minus)) / (2 * h)
        np.testing.assert_allclose(A @ qdd + bias, rate, rtol=1e-6, atol=1e-5)
        a_fd, _ = KinematicsScratch(m, body3d.foot_bodies, SPATIAL_ROWS).biases(d.qpos.copy(), d.qvel.copy())
        np.testing.assert_allclose(bias, a_fd, rtol=1e-6, atol=1e-6)
    assert checked == 100


def test_the_planar_momentum_is_the_spatial_rows_bit_for_bit():
    """One set of formulas: the planar kernel's [L_x, L_z, H_y] are the spatial function's rows, identical."""
    ch = character()
    m = ch.model
    chain = PlanarKinematics(m).chain
    for d in _planar_states(m, seed=3):
        A, bias = kernel.centroidal(d.cdof, d.cdof_dot, d.cvel, d.cinert, d.qvel.copy(), chain)
        A6, bias6 = kernel.centroidal_spatial(d.cdof, d.cdof_dot, d.cvel, d.cinert, d.qvel.copy(), chain)
        assert np.array_equal(A, A6[list(PLANAR_ROWS)]) and np.array_equal(bias, bias6[list(PLANAR_ROWS)])
        assert not A6[1].any()  # no sideways momentum; H_x and H_z it has (legs and arms off the plane), but its
        # joints keep it in the plane: the world takes those up, and the controller does not ask for them
        np.testing.assert_array_equal(foot_jacobian(m, d, ch.foot_bodies[0]),
                                      foot_jacobian(m, d, ch.foot_bodies[0], SPATIAL_ROWS)[list(PLANAR_ROWS)])


def test_a_foot_points_frame_matches_mujoco_in_3d(body3d):
    """The kernel's spatial point Jacobian is MuJoCo's ``mj_jac`` at a 3D foot's contact point, and its bias the
    material point's acceleration at qdd = 0 (central differences along a random qdd)."""
    m = body3d.model
    chain = PlanarKinematics(m).chain
    rng = np.random.default_rng(11)
    for k in range(8):
        d = _random_state(m, rng)
        foot = body3d.foot_bodies[k % 2]
        point = d.geom_xpos[body3d.foot_points[k % 2][k % 4]].copy()
        J, bias = kernel.point_frame_spatial(d.cdof, d.cdof_dot, d.cvel, d.qvel.copy(), chain[foot], foot, point,
                                             d.subtree_com[1])
        jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        mujoco.mj_jac(m, d, jacp, jacr, point, foot)
        np.testing.assert_allclose(J, np.vstack([jacp, jacr]), rtol=0, atol=1e-12)
        local = d.xmat[foot].reshape(3, 3).T @ (point - d.xpos[foot])
        qdd, h = rng.normal(scale=5.0, size=m.nv), 1e-6
        rate = (_point_velocity(m, d, foot, local, qdd, h) - _point_velocity(m, d, foot, local, qdd, -h)) / (2 * h)
        np.testing.assert_allclose(J @ qdd + bias, rate, rtol=1e-6, atol=1e-5)


def _point_velocity(m, d, foot, local, qdd, h):
    """[linear, angular] velocity of a foot's material point (``local`` in its frame) at q(t + h), qd(t + h)."""
    s = mujoco.MjData(m)
    s.qpos[:] = d.qpos
    mujoco.mj_integratePos(m, s.qpos, d.qvel + 0.5 * h * qdd, h)  # q + h qd + h^2/2 qdd
    s.qvel[:] = d.qvel + h * qdd
    mujoco.mj_forward(m, s)
    p = s.xpos[foot] + s.xmat[foot].reshape(3, 3) @ local
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    mujoco.mj_jac(m, s, jp, jr, p, foot)
    return np.concatenate([jp @ s.qvel, jr @ s.qvel])


def test_the_planar_point_frame_is_the_spatial_rows_bit_for_bit():
    ch = character()
    m = ch.model
    chain = PlanarKinematics(m).chain
    for k, d in enumerate(_planar_states(m, seed=5)):
        foot = ch.foot_bodies[k % 2]
        point = d.geom_xpos[ch.foot_points[k % 2][0]]
        args = (d.cdof, d.cdof_dot, d.cvel, d.qvel.copy(), chain[foot], foot, point, d.subtree_com[1])
        J, bias = kernel.point_frame(*args)
        J6, bias6 = kernel.point_frame_spatial(*args)
        assert np.array_equal(J, J6[list(PLANAR_ROWS)]) and np.array_equal(bias, bias6[list(PLANAR_ROWS)])


def test_a_standing_pose_of_the_3d_body_is_the_planar_one(body3d):
    """Feet flat, CoM over the support's centre: the 3D body stands as the planar body does (same root place and
    pitch, same joint angles, the balance joint solved to the same angle), its CoM on the midline."""
    from cmrt.body.character import feet_flat_qpos, joint_angles_from_pose, support_interval_x

    pose = {"hip": -0.3, "knee": 0.5, "lumbar": 0.2, "shoulder": -0.4}
    q3 = feet_flat_qpos(joint_angles_from_pose(pose, "humanoid3d"), body="humanoid3d")
    q2 = feet_flat_qpos(joint_angles_from_pose(pose))
    m = body3d.model
    d = mujoco.MjData(m)
    d.qpos[:] = q3
    mujoco.mj_forward(m, d)
    points = d.geom_xpos[list(body3d.foot_points[0] + body3d.foot_points[1])]
    np.testing.assert_allclose(points[:, 2], 0.01, atol=1e-9)  # all eight points on the floor: feet flat
    lo, hi = support_interval_x(d, body="humanoid3d")
    assert abs(d.subtree_com[1, 0] - 0.5 * (lo + hi)) < 1e-9 and abs(d.subtree_com[1, 1]) < 1e-12
    pitch3 = 2.0 * np.arctan2(q3[5], q3[3])  # the root quaternion turns about y only
    assert q3[4] == q3[6] == 0.0
    pelvis_z = character().model.body("pelvis").pos[2]  # the planar slides move the pelvis from its MJCF place,
    np.testing.assert_allclose([q3[0], q3[2], pitch3], [q2[0], q2[1] + pelvis_z, q2[2]], atol=1e-9)  # a free joint
    # places it absolutely
    planar = character().model
    for j in range(3, planar.njnt):
        name = planar.joint(j).name
        assert q3[m.joint(name).qposadr[0]] == pytest.approx(q2[planar.joint(j).qposadr[0]], abs=1e-9), name
    sided = joint_angles_from_pose({"hip_roll": 0.1, "ankle_roll_l": -0.2}, "humanoid3d")
    assert (sided["hip_roll_r"], sided["hip_roll_l"], sided["ankle_roll_l"]) == (0.1, 0.1, -0.2)
    with pytest.raises(CmrtError, match="unknown joint 'hip_roll'"):
        joint_angles_from_pose({"hip_roll": 0.1})  # the planar body has none


def test_the_feet_sense_the_ground_in_3d(body3d):
    """Held in its standing pose by stiff joint springs (no balance controller yet), the 3D body's eight touch
    sensors carry its weight, and the CoP they give in x and y is the CoP of MuJoCo's contact forces."""
    from cmrt.body.character import feet_flat_qpos, joint_angles_from_pose

    m = body3d.model
    d = mujoco.MjData(m)
    d.qpos[:] = feet_flat_qpos(joint_angles_from_pose({"knee": 0.2, "hip": -0.1}, "humanoid3d"), body="humanoid3d")
    q_hold = d.qpos.copy()
    joints = m.actuator_trnid[:, 0]
    qadr, dadr = m.jnt_qposadr[joints], m.jnt_dofadr[joints]
    points = [g for foot in body3d.foot_points for g in foot]
    for _ in range(250):  # 0.5 s; an explicit PD of 2000 N m/rad and 50 N m s/rad, stable on the 0.01 s contact,
        # chattered and toppled on the heel pad's 0.015 s (the light feet's discrete loop): 1000 and 30 stand still
        d.ctrl[:] = np.clip(1000.0 * (q_hold[qadr] - d.qpos[qadr]) - 30.0 * d.qvel[dadr], *m.actuator_ctrlrange.T)
        mujoco.mj_step(m, d)
    mujoco.mj_forward(m, d)
    sensed = d.sensordata[:8].copy()
    xy = d.geom_xpos[points, :2]
    assert abs(sensed.sum() - body3d.mass_kg * 9.81) < 0.05 * body3d.mass_kg * 9.81  # standing still: the weight
    f6, normal, moment = np.zeros(6), 0.0, np.zeros(2)
    for i in range(d.ncon):
        mujoco.mj_contactForce(m, d, i, f6)
        normal += f6[0]
        moment += f6[0] * d.contact[i].pos[:2]
    assert sensed.sum() == pytest.approx(normal, rel=1e-9)
    np.testing.assert_allclose(sensed @ xy / sensed.sum(), moment / normal, atol=1e-6)


def test_each_leg_names_its_sagittal_chain_on_both_bodies(body3d):
    planar = character()
    for ch in (planar, body3d):
        names = [[ch.dof_names[j] for j in leg] for leg in ch.leg_dofs]
        assert names == [["hip_r", "knee_r", "ankle_r"], ["hip_l", "knee_l", "ankle_l"]]
