"""``cmrt.control.references``: Yu's reactive reference CoM and Winter's reference CoP, checked against MuJoCo.

* Winter's ``I / (W h)`` from com-based inertias against the same sum built body by body from MuJoCo's
  world-frame inertias (``ximat``, ``body_inertia``, ``xipos``), on random poses.
* The reference motion's foot-to-CoM vector against ``subtree_com`` and ``xpos`` of the reference pose,
  and its rate against a finite difference along the reference.
* ``YuReference.targets``: eq. 3.2-3.4 on hand-made states (weights, CMRT, clipping).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from cmrt.body.character import GRAVITY_M_S2, character
from cmrt.control.references import WinterPendulum, YuReference, motion_com
from cmrt.motion.taskfile import load_task

V03_BEND = Path(__file__).parent.parent / "data" / "v03_bend.toml"  # the bend shipped until v0.3


def _state(q: np.ndarray):
    ch = character()
    d = mujoco.MjData(ch.model)
    d.qpos[:] = q
    mujoco.mj_kinematics(ch.model, d)
    mujoco.mj_comPos(ch.model, d)
    return ch, d


def _winter_by_bodies(ch, d, ankle_body: int) -> float:
    """I / (W h) about the ankle, body by body: I_b (rotated to the world) + m_b |x_b - a|^2 over the
    humanoid without its feet."""
    m = ch.model
    a = d.xpos[ankle_body]
    inertia = mass = mz = 0.0
    for b in range(1, m.nbody):
        if b in ch.foot_bodies:
            continue
        R = d.ximat[b].reshape(3, 3)
        world = R @ np.diag(m.body_inertia[b]) @ R.T
        r = d.xipos[b] - a
        inertia += world[1, 1] + m.body_mass[b] * (r[0] ** 2 + r[2] ** 2)
        mass += m.body_mass[b]
        mz += m.body_mass[b] * r[2]
    return inertia / (mass * GRAVITY_M_S2 * (mz / mass))


@pytest.mark.parametrize("seed", range(5))
def test_winter_ratio_matches_a_body_by_body_sum(seed):
    ch = character()
    rng = np.random.default_rng(seed)
    q = load_task("bend").start_qpos() + rng.normal(0.0, 0.3, ch.nv)
    _, d = _state(q)
    pend = WinterPendulum(ch)
    for foot in ch.foot_bodies:
        a = d.xpos[foot]
        got = pend.ratio_s2(d.cinert[None], d.subtree_com[1][None], a[None, 0], a[None, 2])[0]
        assert got == pytest.approx(_winter_by_bodies(ch, d, foot), rel=1e-12)


def test_winter_ratio_of_quiet_standing_is_a_tall_pendulum():
    """Standing, the body above the ankles is a pendulum ~0.9 m tall: I / (W h) a little over h / g."""
    ch, d = _state(load_task("stand").start_qpos())
    a = d.xpos[ch.foot_bodies[0]]
    ratio = WinterPendulum(ch).ratio_s2(d.cinert[None], d.subtree_com[1][None], a[None, 0], a[None, 2])[0]
    h = d.subtree_com[1, 2] - a[2]
    assert h / GRAVITY_M_S2 < ratio < 1.5 * h / GRAVITY_M_S2


def test_motion_com_is_the_reference_poses_com_relative_to_each_ankle():
    ch = character()
    task = load_task(str(V03_BEND)).with_speed(0.4)  # a bend whose CoM travels over the feet
    dt = 0.002
    times = np.arange(0.0, task.clip_s, dt)
    q, qd, _ = task.reference(times)
    mc = motion_com(ch, q, qd)
    for k in (0, 520, 600, 650, 700, 1000):
        _, d = _state(q[k])
        for f, body in enumerate(ch.foot_bodies):
            assert mc.foot_to_com_x_m[k, f] == pytest.approx(d.subtree_com[1, 0] - d.xpos[body, 0], abs=1e-12)
    fd = np.gradient(mc.foot_to_com_x_m, dt, axis=0)
    inside = slice(505, 695)  # the bend (P = 1.0 s, T = 0.4 s), away from the ends of the easing
    assert np.max(np.abs(fd[inside] - mc.foot_to_com_vel_x_m_s[inside])) < 1e-3 * np.max(np.abs(fd[inside]))
    assert np.max(np.abs(mc.foot_to_com_x_m[:, 0])) > 0.1  # the bend's CoM really moves over the feet


def _targets(yu, **over):
    base = dict(foot_force_n=np.array([[350.0, 350.0]]), ankle_xz=np.array([[[0.0, 0.07], [0.0, 0.07]]]),
                foot_to_com_x=np.array([[0.06, 0.06]]), foot_to_com_vel_x=np.zeros((1, 2)), disp_m=np.zeros(1),
                disp_vel_m_s=np.zeros(1), com=np.array([[0.06, 0.0, 0.97]]), com_vel_x=np.zeros(1),
                support_lo_x=np.array([-0.06]), support_hi_x=np.array([0.18]))
    ch, d = _state(load_task("stand").start_qpos())
    base["cinert"] = d.cinert[None]
    base["com"] = d.subtree_com[1][None]
    base.update(over)
    return yu.targets(**base), base


def test_yu_targets_follow_eq_3_2_to_3_4():
    ch = character()
    yu = YuReference(ch, k_l=10.0, d_l=6.0)
    _, base = _targets(yu)
    c = base["com"][0, 0]
    # a state on its reference, at rest: no acceleration wanted, the reference CoP is under the CoM
    on_ref, _ = _targets(yu, foot_to_com_x=np.array([[c, c]]))
    assert on_ref.com_x_m[0] == pytest.approx(c) and on_ref.cop_x_m[0] == pytest.approx(c)
    # eq. 3.3: the more loaded foot pulls the reference CoM toward where its own vector puts it
    t, _ = _targets(yu, foot_force_n=np.array([[600.0, 200.0]]), ankle_xz=np.array([[[0.1, 0.07], [0.0, 0.07]]]),
                    foot_to_com_x=np.array([[0.02, 0.05]]))
    assert t.com_x_m[0] == pytest.approx(0.75 * (0.1 + 0.02) + 0.25 * (0.0 + 0.05))
    # no load: both feet count half
    t, _ = _targets(yu, foot_force_n=np.zeros((1, 2)), ankle_xz=np.array([[[0.1, 0.07], [0.0, 0.07]]]),
                    foot_to_com_x=np.array([[0.0, 0.0]]))
    assert t.com_x_m[0] == pytest.approx(0.05)
    # the CMRT adds to the reference CoM and its rate, and Winter's CoP follows the CoM target it makes
    t, _ = _targets(yu, foot_to_com_x=np.array([[c, c]]), disp_m=np.array([0.01]), disp_vel_m_s=np.array([0.02]))
    assert t.com_x_m[0] == pytest.approx(c + 0.01) and t.com_vel_x_m_s[0] == pytest.approx(0.02)
    pend = WinterPendulum(ch)
    ratio = pend.ratio_s2(base["cinert"], base["com"], np.zeros(1), np.full(1, 0.07))[0]
    acc = 10.0 * 0.01 + 6.0 * 0.02
    assert t.cop_x_m[0] == pytest.approx(c - ratio * acc)  # a CoM target ahead: the CoP moves behind the CoM
    assert t.cop_x_m[0] < c
    # clipped to the support
    t, _ = _targets(yu, foot_to_com_x=np.array([[c, c]]), disp_m=np.array([-1.0]))
    assert t.cop_x_m[0] == pytest.approx(0.18)
