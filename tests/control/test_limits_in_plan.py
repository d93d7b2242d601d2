"""Motor limits and joint stops as rows of the QP (``ControllerConfig.limits_in_plan``, issue 25): the plan is
one the motors can carry out, so what MuJoCo does with its torques is what was planned."""

import dataclasses
from pathlib import Path

import mujoco
import numpy as np
import pytest

from cmrt.body.character import character
from cmrt.control import ControllerConfig, MomentumBalanceController
from cmrt.control.kernel import LIMIT_SLACK
from cmrt.motion.taskfile import load_task
from cmrt.sim.simulate import CONTROL_FIELDS, _in_contact, simulate

V03_BEND = Path(__file__).parent.parent / "data" / "v03_bend.toml"  # the bend shipped until v0.3

# 40 % of the MJCF's motor limits: the bend's plan needs more than that at some of the states below.
WEAK = 0.4


def _weak_controller(in_plan: bool) -> MomentumBalanceController:
    ch = character()
    c = MomentumBalanceController(ch, ControllerConfig(limits_in_plan=in_plan))
    c.bounds = c.bounds.copy()
    c.bounds[:, 0] *= WEAK
    c.limits = c.bounds[:, 0].copy()
    return c


@pytest.fixture(scope="module")
def bend_states():
    task = load_task(str(V03_BEND)).with_speed(0.8)  # a bend whose weak motors meet their limits
    # knees off their stops, and planned as the test plans (no feedback delay: it calls the controller with the
    # present CoM)
    traj = simulate(task, config=ControllerConfig(limits_in_plan=True, feedback_delay_s=0.0))
    return task.reference(traj.time_s), traj


def _plan_and_apply(controller, refs, traj, k, d):
    ch = character()
    points = np.array(ch.foot_point_geoms)
    q_ref, qd_ref, qdd_ref = (r[k] for r in refs)
    d.qpos[:], d.qvel[:] = traj.qpos[k], traj.qvel[k]
    mujoco.mj_forward(ch.model, d)
    f = {name: getattr(d, name)[None].copy() for name in CONTROL_FIELDS}
    xs = d.geom_xpos[points, 0]
    center = np.array([0.5 * (xs.min() + xs.max())])
    out = controller.torques(f, q_ref, qd_ref, qdd_ref, center, np.zeros(1), center,
                             _in_contact(d.geom_xpos[None], points))
    d.ctrl[:] = out.torque_nm[0]
    mujoco.mj_forward(ch.model, d)
    touch = d.sensordata[:4]
    return out, touch.sum(), (touch * xs).sum() / touch.sum()


def test_the_plan_respects_the_motor_limits_and_is_what_mujoco_applies(bend_states):
    """With the limits in the plan no torque is clipped and the planned ground force and CoP are MuJoCo's;
    with the same limits clipped after the solve (the v0.2 controller) the executed CoP leaves the plan."""
    task, traj = bend_states
    ch = character()
    d = mujoco.MjData(ch.model)
    in_plan, clipped = _weak_controller(True), _weak_controller(False)
    limited = 0
    worst_clipped_cop_m = 0.0
    for k in range(400, 1400, 10):
        out, fz, cop = _plan_and_apply(in_plan, task, traj, k, d)
        assert not out.saturated[0]
        assert np.all(np.abs(out.torque_nm[0]) <= in_plan.limits * (1 + LIMIT_SLACK))
        limited += bool(np.any(np.abs(out.torque_nm[0]) > in_plan.limits * (1 - 1e-3)))
        # MuJoCo's soft contacts regularise the constraint force: measured up to 1.4 % of body weight at the
        # states where the weak motors change the planned force fastest
        assert abs(fz - out.ground_force_n[0, 1]) < 0.02 * ch.mass_kg * 9.81
        assert abs(cop - out.cop_x_m[0]) < 1e-3
        out, fz, cop = _plan_and_apply(clipped, task, traj, k, d)
        if out.saturated[0]:
            worst_clipped_cop_m = max(worst_clipped_cop_m, abs(cop - out.cop_x_m[0]))
    assert limited >= 2  # the rows were active: the test is about them
    assert worst_clipped_cop_m > 5e-3


def test_the_default_controller_is_unchanged_bit_for_bit(bend_states):
    """``limits_in_plan`` off is the v0.2 controller: the rows are not built, so their gains change nothing."""
    task, traj = bend_states
    ch = character()
    d = mujoco.MjData(ch.model)
    default = MomentumBalanceController(ch, ControllerConfig(limits_in_plan=False))
    explicit = MomentumBalanceController(ch, dataclasses.replace(ControllerConfig(), limits_in_plan=False,
                                                                 stop_k=1.0, stop_d=1.0))
    for k in range(400, 1400, 100):
        a, _, _ = _plan_and_apply(default, task, traj, k, d)
        b, _, _ = _plan_and_apply(explicit, task, traj, k, d)
        assert np.array_equal(a.torque_nm, b.torque_nm)


def _max_stop_force_nm(traj) -> float:
    m = character().model
    d = mujoco.MjData(m)
    worst = 0.0
    for k in range(0, traj.time_s.size, 5):
        if traj.protective[k]:
            break
        d.qpos[:], d.qvel[:], d.ctrl[:] = traj.qpos[k], traj.qvel[k], traj.ctrl_nm[k]
        mujoco.mj_forward(m, d)
        stop = d.efc_type == mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT
        if stop.any():
            worst = max(worst, float(np.abs(d.efc_force[stop]).max()))
    return worst


def test_the_plan_keeps_off_the_joint_stops():
    """The rise straightens the knees onto their 0 rad stop: clipped after the solve the stops carry tens of
    N m the plan does not know of; with the stops in the plan they carry nothing."""
    task = load_task("rise")
    on = simulate(task, config=ControllerConfig(limits_in_plan=True))
    off = simulate(task, config=ControllerConfig(limits_in_plan=False))
    assert _max_stop_force_nm(off) > 5.0
    assert _max_stop_force_nm(on) == 0.0
    knees = [character().dof(f"knee_{s}") for s in "rl"]
    before = ~on.protective & np.isfinite(on.qpos[:, 0])
    assert on.qpos[before][:, knees].min() > ControllerConfig().stop_margin_rad - 5e-3
