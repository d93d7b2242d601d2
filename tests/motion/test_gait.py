"""The keyed gait (cmrt.motion.gait): its poses put the feet exactly where its keys say, it starts and ends in the
stand pose, its rates are the angles' own, and a gait the legs cannot do is refused in one line."""

import mujoco
import numpy as np
import pytest

from cmrt import CmrtError, load_task
from cmrt.body.character import character
from cmrt.control.references import motion_com
from cmrt.motion.gait import Gait, gait_motion

TASK = load_task("yu-walk")


def _motion(task=TASK, step_s=0.002):
    t = np.arange(0.0, task.gait.end_s + 0.5, step_s)
    return t, gait_motion(task.gait, character(), task.start_qpos(), t)


def test_the_poses_put_the_feet_on_their_keyed_paths_flat():
    """Forward kinematics (MuJoCo's) of every 20th frame: each ankle where the gait's paths say to 1e-9 m, each
    foot flat, a planted foot still, a swinging one up to ``lift_m`` above the floor."""
    ch = character()
    t, motion = _motion()
    d = mujoco.MjData(ch.model)
    heel_z = []
    for k in range(0, t.size, 20):
        d.qpos[:] = motion.q[k]
        mujoco.mj_kinematics(ch.model, d)
        for f, body in enumerate(ch.foot_bodies):
            assert d.xpos[body, 0] == pytest.approx(motion.ankle_x_m[k, f], abs=1e-9)
            assert d.xpos[body, 2] == pytest.approx(motion.ankle_z_m[k, f], abs=1e-9)
        points = d.geom_xpos[list(ch.foot_point_geoms)]
        assert abs(points[0, 2] - points[1, 2]) < 1e-9 and abs(points[2, 2] - points[3, 2]) < 1e-9  # flat
        heel_z.append(points[[0, 2], 2])
    lift = np.array(heel_z) - heel_z[0]
    assert lift.min() > -1e-9 and lift.max() == pytest.approx(TASK.gait.lift_m, abs=2e-3)


def test_it_starts_and_ends_in_the_stand_pose_having_walked_its_footprints():
    t, motion = _motion()
    stand = TASK.start_qpos()
    np.testing.assert_allclose(motion.q[0], stand, atol=1e-12)
    np.testing.assert_allclose(motion.q[-1, 2:], stand[2:], atol=1e-9)  # the joints; the root walked on
    g = TASK.gait
    assert motion.q[-1, 0] - stand[0] == pytest.approx(g.steps * g.step_length_m)
    np.testing.assert_allclose(motion.ankle_x_m[-1], g.steps * g.step_length_m)  # feet together at the end
    assert [g.foot(j) for j in range(g.n_steps)] == [0, 1, 0, 1, 0, 1, 0]  # right first; the closing step trails


def test_rates_are_the_angles_own():
    """qd and qdd integrate back to q (trapezoid, 1 ms): central differences of a smooth path, whatever the times
    asked for (a single time gives the same rates as a grid)."""
    t, motion = _motion(step_s=0.001)
    def integral(rate):
        return np.cumsum(np.vstack([np.zeros(rate.shape[1]), 0.5 * (rate[1:] + rate[:-1]) * 0.001]), axis=0)

    dofs = list(character().actuated_dofs)
    assert np.abs(motion.q[0] + integral(motion.qd) - motion.q)[:, dofs].max() < 1e-3
    assert np.abs(motion.qd[0] + integral(motion.qdd) - motion.qd)[:, dofs].max() < 0.02
    one = gait_motion(TASK.gait, character(), TASK.start_qpos(), t[1234:1235])
    np.testing.assert_allclose(one.qd[0], motion.qd[1234], atol=1e-9)


def test_the_com_passes_over_the_stance_foot_in_every_swing():
    """Eq. 3.2's r_f(u) from the gait (what the yu reference places on the feet): at every mid-swing the CoM is
    over the stance foot (between its heel and toe; the pelvis is keyed over it as standing, the swing leg's bent
    knee puts the CoM 2 cm further ahead), behind that at lift-off and ahead at touchdown."""
    ch = character()
    g = TASK.gait
    t = np.array([[g.lift_off_s(j), g.lift_off_s(j) + 0.5 * g.swing_s, g.touchdown_s(j)] for j in range(g.steps)])
    q, qd, _ = TASK.reference(t.ravel())
    rel = motion_com(ch, q, qd).foot_to_com_x_m.reshape(g.steps, 3, 2)
    heel, toe = (ch.model.geom_pos[p, 0] for p in ch.foot_point_geoms[:2])  # from the ankle
    for j in range(1, g.steps):  # the first step leaves from feet together: the CoM stays back until mid-swing
        stance = 1 - g.foot(j)
        behind, over, ahead = rel[j, :, stance]
        assert behind < over < ahead
        assert heel < over < toe


@pytest.mark.parametrize("params,match", [
    ({"gait_step_length_m": 0.3}, "out of the leg's reach"),
    ({"gait_steps": 2.5}, "whole number"),
    ({"clip_s": 5.0}, "clip_s must be at least"),
    ({"gait_first_step_s": 0.3}, "gait_first_step_s must be at least 0.5"),
    ({"stepping": 1}, "no footstep plan, end pose or stepping"),
])
def test_a_gait_the_legs_or_the_clip_cannot_do_is_refused(params, match):
    with pytest.raises(CmrtError, match=match) as info:
        TASK.with_params(**params)
    assert "\n" not in str(info.value)


def test_a_task_has_a_gait_only_with_gait_steps():
    assert load_task("walk").gait is None and load_task("stand").gait is None
    assert TASK.gait == Gait.from_params(TASK.params) and TASK.footsteps_planned == TASK.gait.n_steps == 7
    assert TASK.with_params(gait_step_length_m=0.15).content_hash() != TASK.content_hash()


def test_the_pelvis_keeps_the_walking_speed_and_stops_gently():
    """Between the second mid-swing and the stop the pelvis moves at L / (swing + double support), over the stance
    ankle at every mid-swing; it speeds up and slows down with no more than ``STOP_DECEL_M_S2`` (the stop) and
    comes to rest over the feet together."""
    from cmrt.motion.gait import STOP_DECEL_M_S2, pelvis_path

    g = TASK.gait
    t = np.arange(0.0, g.end_s + 0.5, 0.001)
    x = pelvis_path(g, t, 0.05, 0.9)[0]
    v, a = np.gradient(x, t), np.gradient(np.gradient(x, t), t)
    cruising = (t > g.lift_off_s(1) + 0.5 * g.swing_s) & (t < g.stop_s[0])
    np.testing.assert_allclose(v[cruising], g.speed_m_s, rtol=1e-6)
    prints = g.footprints_m()
    for j in range(1, g.steps):
        mid = g.lift_off_s(j) + 0.5 * g.swing_s
        assert np.interp(mid, t, x) == pytest.approx(prints[j, 1 - g.foot(j)] + 0.05, abs=1e-6)
    assert -a[t > g.stop_s[0]].min() <= STOP_DECEL_M_S2 * 1.001
    assert x[-1] == pytest.approx(prints[-1].max() + 0.05, abs=1e-9) and abs(v[-1]) < 1e-9
