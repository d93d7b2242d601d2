"""The planar body's motion on the 3D body (cmrt.body.sagittal): joint by joint by name, the other joints at rest."""

import numpy as np

from cmrt import load_task
from cmrt.body.character import character
from cmrt.body.sagittal import planar_to_3d
from cmrt.sim.spatial import stand_pose_qpos


def test_the_planar_bend_is_the_3d_bodys_joint_for_joint():
    task = load_task("bend").with_speed(0.4)
    t = np.linspace(0.9, 1.5, 7)
    q, qd, qdd = task.reference(t)
    base = stand_pose_qpos()
    q3, qd3, qdd3 = planar_to_3d(q, qd, qdd, base)
    planar, spatial = character(), character("humanoid3d")
    for a in range(planar.model.nu):
        j = planar.model.actuator_trnid[a, 0]
        name = planar.model.joint(j).name
        j3 = spatial.model.joint(name).id
        np.testing.assert_array_equal(q3[:, spatial.model.jnt_qposadr[j3]], q[:, planar.model.jnt_qposadr[j]])
        np.testing.assert_array_equal(qd3[:, spatial.model.jnt_dofadr[j3]], qd[:, planar.model.jnt_dofadr[j]])
        np.testing.assert_array_equal(qdd3[:, spatial.model.jnt_dofadr[j3]], qdd[:, planar.model.jnt_dofadr[j]])
    rolls = [spatial.model.jnt_qposadr[spatial.model.joint(n).id] for n in ("hip_roll_r", "ankle_roll_l", "lumbar_yaw")]
    assert not q3[:, rolls].any() and np.array_equal(q3[:, :7], np.repeat(base[None, :7], len(t), axis=0))
