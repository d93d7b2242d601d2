import mujoco
import numpy as np

from cmrt.body.character import GRAVITY_M_S2, character, feet_flat_qpos, joint_angles_from_pose, support_interval_x


def test_dimensions_mass_and_height():
    ch = character()
    m = ch.model
    assert (m.nq, m.nv, m.nu) == (15, 15, 12)
    assert abs(ch.mass_kg - 70.0) < 0.05
    d = mujoco.MjData(m)
    d.qpos[:] = feet_flat_qpos(joint_angles_from_pose({}), balance_joint=None)
    mujoco.mj_forward(m, d)
    head = d.geom("head")
    top = head.xpos[2] + m.geom("head").size[0] + m.geom("head").size[1]
    assert abs(top - 1.75) < 0.02
    assert abs(d.geom("heel_r").xpos[2] - 0.01) < 1e-9  # sphere resting on the floor


def test_winter_segment_masses():
    m = character().model
    fractions = {
        "thigh_r": 0.100,
        "shank_r": 0.0465,
        "foot_r": 0.0145,
        "upper_arm_r": 0.028,
        "forearm_r": 0.016 + 0.006,
        "head": 0.081,
    }
    for body, frac in fractions.items():
        assert abs(m.body(body).mass[0] - 70 * frac) < 0.01, body
    trunk = m.body("pelvis").mass[0] + m.body("thorax").mass[0]
    assert abs(trunk - 70 * 0.497) < 0.01


def test_balanced_pose_puts_com_over_support_center():
    ch = character()
    m = ch.model
    d = mujoco.MjData(m)
    d.qpos[:] = feet_flat_qpos(joint_angles_from_pose({"hip": np.radians(-60), "lumbar": np.radians(20)}))
    mujoco.mj_forward(m, d)
    lo, hi = support_interval_x(d)
    assert abs(d.subtree_com[0, 0] - 0.5 * (lo + hi)) < 1e-9
    for heel, toe in ch.foot_points:
        assert abs(d.geom_xpos[heel, 2] - d.geom_xpos[toe, 2]) < 1e-9  # feet flat


def test_the_gravity_constant_is_the_models():
    """One gravity for the whole package (controller, fall monitor, props, objective): the MJCF's."""
    assert character().model.opt.gravity.tolist() == [0.0, 0.0, -GRAVITY_M_S2]


def test_the_foot_points_are_a_heel_pads_contact():
    """MuJoCo averages two geoms' solref (solmix 1 each): foot points at 0.02 s on the 0.01 s floor are a 0.015 s
    contact (the heel pad of humanoid.xml), not the 0.02 s their class names - on both bodies."""
    for body in ("planar", "humanoid3d"):
        ch = character(body)
        m, d = ch.model, mujoco.MjData(ch.model)
        d.qpos[:] = feet_flat_qpos(joint_angles_from_pose({}), balance_joint=None, body=body)
        d.qpos[1 if body == "planar" else 2] -= 0.002  # the root 2 mm lower: every foot point 2 mm into the floor
        mujoco.mj_forward(m, d)
        feet = [c for c in d.contact[: d.ncon] if set(c.geom) & set(ch.foot_point_geoms)]
        assert len(feet) == len(ch.foot_point_geoms), body
        assert all(np.allclose(c.solref, [0.015, 1.0]) for c in feet), body
