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


def test_the_3d_body_playing_the_planar_bend_has_the_planar_centroidal_dynamics():
    """The same sagittal motion on both bodies: the same CoM, linear momentum and angular momentum about the CoM
    (the lateral ones zero), so the same ground force and CoP - what `cmrt check` relies on for a 3D pose change."""
    import mujoco

    from cmrt.body.sagittal import planar_state_to_3d

    task = load_task("bend").with_speed(0.4)
    q, qd, _ = task.reference(np.linspace(0.95, 1.45, 11))
    pm, sm = character().model, character("humanoid3d").model
    pd, sd = mujoco.MjData(pm), mujoco.MjData(sm)
    for k in range(len(q)):
        pd.qpos[:], pd.qvel[:] = q[k], qd[k]
        sd.qpos[:], sd.qvel[:] = planar_state_to_3d(q[k], qd[k], stand_pose_qpos())
        for m, d in ((pm, pd), (sm, sd)):
            mujoco.mj_forward(m, d)
            mujoco.mj_subtreeVel(m, d)
        np.testing.assert_allclose(sd.subtree_com[1], pd.subtree_com[1], atol=1e-12)
        np.testing.assert_allclose(sd.subtree_linvel[1], pd.subtree_linvel[1], atol=1e-12)
        np.testing.assert_allclose(sd.subtree_angmom[1], pd.subtree_angmom[1], atol=1e-12)
