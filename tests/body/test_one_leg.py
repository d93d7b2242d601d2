"""The 3D body's one-leg poses (cmrt.body.one_leg): the stance foot flat where it stood, the CoM over it, the other
foot lifted level; the same on either side."""

import mujoco
import numpy as np
import pytest

from cmrt.body.character import character
from cmrt.body.one_leg import one_leg_poses
from cmrt.sim.spatial import stand_pose_qpos


def _kin(q):
    m = character("humanoid3d").model
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    return d


@pytest.mark.parametrize("stance", [0, 1])
def test_the_stance_foot_stays_and_carries_the_com_and_the_other_lifts(stance):
    ch = character("humanoid3d")
    poses = one_leg_poses(stand_pose_qpos(), stance)
    standing, shifted, lifted = (_kin(q) for q in (poses.standing, poses.shifted, poses.lifted))
    foot, other = ch.foot_bodies[stance], ch.foot_bodies[1 - stance]
    for d in (shifted, lifted):
        np.testing.assert_allclose(d.xpos[foot], standing.xpos[foot], atol=1e-12)
        assert d.xmat[foot][8] == pytest.approx(1.0, abs=1e-6)  # flat within 0.08 deg: the hip's and the ankle's
        # roll axes are parallel only up to the standing pose's ankle pitch (measured 0.03 deg)
    assert lifted.subtree_com[1, 1] == pytest.approx(poses.stance_centre_xy_m[1], abs=1e-6)
    assert lifted.xpos[other][2] - standing.xpos[other][2] == pytest.approx(0.10, abs=0.01)
    assert lifted.xmat[other][8] > np.cos(np.radians(1.0))  # the lifted sole within 1 deg of level (0.67: the hip's
    # roll about a flexed thigh)
    assert np.degrees(poses.roll_rad) == pytest.approx(6.5, abs=0.5)  # asin(9 cm / 86 cm of leg), about
    np.testing.assert_allclose(shifted.xpos[other], standing.xpos[other], atol=0.005)  # still on the floor


def test_the_sides_mirror():
    right, left = (one_leg_poses(stand_pose_qpos(), s) for s in (0, 1))
    assert right.roll_rad == pytest.approx(left.roll_rad, rel=1e-9)
    assert right.stance_centre_xy_m[1] == pytest.approx(-left.stance_centre_xy_m[1], abs=1e-12)
