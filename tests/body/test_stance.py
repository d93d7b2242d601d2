"""The stance over given feet (cmrt.body.stance): checked against MuJoCo's own kinematics and centre of mass."""

import mujoco
import numpy as np
import pytest

from cmrt.body.character import FOOT_POINT_RADIUS_M, character, support_interval_x
from cmrt.body.stance import feet_heel_x, leg_offsets, stance_qpos
from cmrt.errors import CmrtError
from cmrt.motion.taskfile import load_task


def _kinematics(qpos: np.ndarray) -> mujoco.MjData:
    ch = character()
    d = mujoco.MjData(ch.model)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(ch.model, d)
    mujoco.mj_comPos(ch.model, d)
    return d


def test_with_the_feet_where_the_pose_has_them_the_stance_is_the_pose():
    pose = load_task("stand").end_qpos()
    assert np.allclose(stance_qpos(pose, feet_heel_x(pose)), pose, atol=1e-9)
    assert np.allclose(leg_offsets(pose, *feet_heel_x(pose)), 0.0, atol=1e-9)


@pytest.mark.parametrize("heels", [(0.24, 0.54), (0.30, -0.06), (-0.36, -0.06), (0.10, 0.12)])
def test_a_split_stance_stands_flat_on_its_feet_with_the_com_over_their_centre(heels):
    pose = load_task("stand").end_qpos()
    q = stance_qpos(pose, heels)
    d = _kinematics(q)
    ch = character()
    for foot, heel_x in enumerate(heels):
        heel, toe = (d.geom_xpos[g] for g in ch.foot_points[foot])
        assert heel[0] == pytest.approx(heel_x, abs=1e-9)
        assert heel[2] == pytest.approx(FOOT_POINT_RADIUS_M, abs=1e-9)
        assert toe[2] == pytest.approx(FOOT_POINT_RADIUS_M, abs=1e-9)  # flat
    lo, hi = support_interval_x(d)
    assert d.subtree_com[0, 0] == pytest.approx(0.5 * (lo + hi), abs=1e-9)
    dofs = [3, 4, 5, 6, 7, 8]  # lumbar, neck, arms: the pose's upper body, and its pelvis pitch
    assert np.array_equal(q[dofs], pose[dofs]) and q[2] == pose[2]
    knees = q[[character().dof("knee_r"), character().dof("knee_l")]]
    # the farther leg as posed (a straight knee to 1e-7: acos near 1 keeps half the digits)
    assert knees.min() == pytest.approx(pose[character().dof("knee_r")], abs=1e-7)
    lo_r, hi_r = character().joint_range_rad()
    joints = q[list(character().actuated_dofs)]
    assert np.all(joints >= lo_r - 1e-9) and np.all(joints <= hi_r + 1e-9)


def test_feet_too_far_apart_have_no_stance_and_the_supervisor_keeps_the_reference():
    pose = load_task("stand").end_qpos()
    with pytest.raises(CmrtError, match="apart"):
        stance_qpos(pose, (-0.06, 1.8))
    assert np.array_equal(leg_offsets(pose, -0.06, 1.8), np.zeros(6))


def test_a_final_pose_over_feet_no_stance_reaches_is_infinitely_far():
    """A clip that ends split wider than any stance (a split fall) is scored, not crashed: its final pose error
    is inf; a split a stance reaches has a finite one."""
    task = load_task("push-recovery")
    assert np.isfinite(task.final_pose_error_rad(stance_qpos(task.end_qpos(), (-0.06, 1.5))))
    split = task.end_qpos()
    split[character().dof("hip_r")], split[character().dof("hip_l")] = 1.45, -1.45  # legs splayed, straight
    heels = feet_heel_x(split)
    assert abs(heels[1] - heels[0]) > 1.72
    assert task.final_pose_error_rad(split) == float("inf")
