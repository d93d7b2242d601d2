"""The 3D momentum controller's plan (cmrt.control.spatial): point forces inside their cones, the body's weight
carried, torques within the motors' limits; a body without a free root refused."""

import mujoco
import numpy as np
import pytest

from cmrt.body.character import character
from cmrt.control.controller import ControllerConfig
from cmrt.control.spatial import SpatialController
from cmrt.errors import CmrtError
from cmrt.sim.spatial import BODY, stand_3d, stand_pose_qpos


def _standing():
    ch = character(BODY)
    d = mujoco.MjData(ch.model)
    d.qpos[:] = stand_pose_qpos()
    rng = np.random.default_rng(3)
    d.qvel[:] = 0.05 * rng.standard_normal(ch.model.nv)
    mujoco.mj_forward(ch.model, d)
    return ch, d


def test_the_plan_keeps_every_point_in_its_cone_and_carries_the_body():
    ch, d = _standing()
    config = ControllerConfig()
    ctl = SpatialController(ch, d.qpos.copy(), config)
    plan = ctl.plan(d, np.ones(len(ch.foot_point_geoms), bool))
    f = plan.point_force_n
    assert not ctl.infeasible
    assert (f[:, 2] >= ctl.point_floor_n - 1e-6).all()
    assert (np.abs(f[:, :2]).sum(axis=1) <= config.friction_coef * f[:, 2] + 1e-6).all()  # MuJoCo's pyramid
    assert np.abs(plan.torque_nm * ch.model.actuator_gear[:, 0]).max() <= ch.torque_limit_nm.max() + 1e-6
    weight_n = ctl.mass_kg * 9.81
    assert abs(f[:, 2].sum() - weight_n) < 0.1 * weight_n  # the momentum objectives ask for little vertical motion
    xy = d.geom_xpos[list(ch.foot_point_geoms), :2]
    assert xy[:, 0].min() < plan.cop_xy_m[0] < xy[:, 0].max()
    assert xy[:, 1].min() < plan.cop_xy_m[1] < xy[:, 1].max()


def test_mujocos_friction_on_the_floor_is_a_diamond_in_the_worlds_axes():
    """What the plan's friction rows must match: MuJoCo's default (pyramidal) cone spans n +- mu t1, n +- mu t2, so
    |f_t1| + |f_t2| <= mu f_n. A 1 kg ball on three slide joints (it cannot roll), mu 1, pushed for 1 s: along an
    axis 0.9 of its weight only creeps (soft contact), along the diagonal 0.75 - past 1/sqrt(2) - it slides; and
    the 3D body's foot points touch the floor with the world's y and -x as their tangents."""
    xml = """<mujoco><worldbody><geom type="plane" size="5 5 .1"/><body pos="0 0 0.1">
      <joint type="slide" axis="1 0 0"/><joint type="slide" axis="0 1 0"/><joint type="slide" axis="0 0 1"/>
      <geom type="sphere" size="0.1" mass="1"/></body></worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)

    def moved_m(share: float, angle_deg: float) -> float:
        d = mujoco.MjData(m)
        force = share * 9.81 * np.array([np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg)), 0.0])
        for _ in range(500):
            d.xfrc_applied[1, :3] = force
            mujoco.mj_step(m, d)
        return float(np.hypot(*d.qpos[:2]))

    assert moved_m(0.9, 0.0) < 0.05 and moved_m(0.9, 90.0) < 0.05 and moved_m(0.75, 45.0) > 0.1
    ch, d = _standing()
    frames = np.array([c.frame.reshape(3, 3) for c in d.contact[:d.ncon]])
    assert d.ncon >= 8 and np.allclose(frames[:, 1:], [[0, 1, 0], [-1, 0, 0]])


def test_a_diagonal_push_keeps_every_planned_force_in_mujocos_cone(monkeypatch):
    """Pushed at 45 deg the plan asks the points for sideways and fore-aft friction at once: every planned force
    stays in MuJoCo's pyramid scaled by ``friction_coef`` (|f_x| + |f_y| <= 0.8 f_z) - at its edge in many steps,
    where the first plan's box (|f_x|, |f_y| <= 0.8 f_z) went past it."""
    forces = []
    plan = SpatialController.plan

    def recorded(self, *args, **kwargs):
        out = plan(self, *args, **kwargs)
        forces.append(out.point_force_n)
        return out

    monkeypatch.setattr(SpatialController, "plan", recorded)
    stand_3d(clip_s=1.5, push_n=(120.0, 120.0, 0.0), push_start_s=0.5, push_duration_s=0.1,
             compiled=False)  # the Python loop calls ``plan`` (the compiled one is the same clip)
    f = np.concatenate(forces)
    loaded = f[:, 2] > 1.0
    ratio = np.abs(f[loaded, :2]).sum(axis=1) / f[loaded, 2]
    mu = ControllerConfig().friction_coef
    assert ratio.max() <= mu + 1e-6 and (ratio > mu - 1e-3).sum() > 50


def test_unloaded_points_carry_nothing():
    ch, d = _standing()
    ctl = SpatialController(ch, d.qpos.copy())
    loaded = np.ones(len(ch.foot_point_geoms), bool)
    loaded[:4] = False  # the right foot off the floor
    plan = ctl.plan(d, loaded)
    assert np.abs(plan.point_force_n[:4]).max() < 1e-6
    assert plan.point_force_n[4:, 2].sum() > 0.5 * ctl.mass_kg * 9.81


def test_a_planar_body_is_refused():
    with pytest.raises(CmrtError, match="free root"):
        SpatialController(character("planar"), np.zeros(character("planar").model.nq))


def test_a_swinging_foot_carries_nothing_and_the_targets_move_the_references():
    from cmrt.control.spatial import SpatialTargets

    ch, d = _standing()
    ctl = SpatialController(ch, d.qpos.copy())
    lifted = d.xpos[ch.foot_bodies[0]] + np.array([0.0, 0.0, 0.05])
    plan = ctl.plan(d, np.ones(len(ch.foot_point_geoms), bool),
                    SpatialTargets(cop_xy_m=np.array([0.06, 0.09]), swing_foot=0, swing_pos_m=lifted,
                                   swing_vel_m_s=np.zeros(3)))
    assert np.abs(plan.point_force_n[:4]).max() < 1e-6  # touching, but lifting: no load planned on it
    assert plan.cop_xy_m[1] > 0.05  # the CoP on the left foot, the one left to stand on


def _held_load_gap_m(told: bool) -> tuple[float, float]:
    """The 3D body standing 1 s with 80 N pulling its right forearm down and forward (MuJoCo's xfrc_applied, at the
    forearm's CoM), the plan told of the load or not: the largest planned-vs-executed CoP gap (m) after the first
    0.1 s, and the planned ground force over the body's weight at the end."""
    ch = character(BODY)
    m = ch.model
    d = mujoco.MjData(m)
    d.qpos[:] = stand_pose_qpos()
    mujoco.mj_forward(m, d)
    ctl = SpatialController(ch, d.qpos.copy())
    forearm = m.body("forearm_r").id
    force = np.array([20.0, 0.0, -80.0])
    points = list(ch.foot_point_geoms)
    gap, planned, ratio = 0.0, np.full(2, np.nan), 0.0
    for k in range(int(1.0 / m.opt.timestep)):
        if k % ctl.config.control_every == 0:
            touch = d.sensordata[:len(points)].copy()
            cop = touch @ d.geom_xpos[points, :2] / touch.sum()
            if k * m.opt.timestep >= 0.1:
                gap = max(gap, float(np.abs(cop - planned).max()))
            jac = np.empty((3, m.nv))
            mujoco.mj_jac(m, d, jac, None, d.xipos[forearm], forearm)  # the load's generalized force, J^T f
            plan = ctl.plan(d, touch > 0.0, load_gen=jac.T @ force if told else None)
            d.ctrl[:] = plan.torque_nm
            planned = plan.cop_xy_m
            ratio = plan.point_force_n[:, 2].sum() / (ctl.mass_kg * 9.81)
        d.xfrc_applied[forearm, :3] = force
        mujoco.mj_step(m, d)
    return gap, ratio


def test_a_held_load_known_to_the_plan_is_what_happens():
    """A load on the hands (a caught ball's pull) enters the plan as the planar kernel's does - the base moves under
    the ground's forces and it, the torques take it out - so the planned CoP is the executed one; a plan that does
    not know of it is off by centimetres."""
    told_gap, told_ratio = _held_load_gap_m(True)
    blind_gap, _ = _held_load_gap_m(False)
    assert told_gap < 0.001
    assert blind_gap > 0.01
    assert told_ratio == pytest.approx(1.0 + 80.0 / (character(BODY).mass_kg * 9.81), rel=0.02)


def test_with_no_plan_inside_the_motors_limits_the_plan_leaves_them_out_and_clips():
    """Where no plan meets the motors' limits (here limits no torque meets: -1 N m, bounds crossed) the QP with their
    rows has no solution, so the step plans without them - a fall's last steps still need torques - clips the
    torques after the solve and says so; with the limits back the next step plans within them again."""
    ch, d = _standing()
    ctl = SpatialController(ch, d.qpos.copy())
    ctl._body[7][:] = -1.0  # the motors' limits (N m) as the compiled step reads them
    plan = ctl.plan(d, np.ones(len(ch.foot_point_geoms), bool))
    assert ctl.infeasible
    assert np.allclose(plan.torque_nm * ch.model.actuator_gear[:, 0], -1.0)  # clipped into [1, -1]: its upper end
    assert plan.point_force_n[:, 2].sum() > 0.5 * ctl.mass_kg * 9.81  # the ground still carries the body
    ctl._body[7][:] = ch.torque_limit_nm
    plan = ctl.plan(d, np.ones(len(ch.foot_point_geoms), bool))
    assert not ctl.infeasible
    assert (np.abs(plan.torque_nm * ch.model.actuator_gear[:, 0]) <= ch.torque_limit_nm + 1e-6).all()


def test_torques_that_are_not_finite_are_refused(monkeypatch):
    """A plan whose torques are not finite is no plan (the clip counts it a fall): MuJoCo, handed a NaN, warns
    "simulation is unstable" and resets the clip's state - a fault that once came from the QP's warm start."""
    from cmrt.control import spatial_kernel

    ch, d = _standing()
    ctl = SpatialController(ch, d.qpos.copy())
    step = spatial_kernel.plan_step

    def nan_torques(*args):
        torque, forces, cop, status, limited = step(*args)
        return torque * np.nan, forces, cop, status, limited

    monkeypatch.setattr(spatial_kernel, "plan_step", nan_torques)
    with pytest.raises(CmrtError, match="not finite"):
        ctl.plan(d, np.ones(len(ch.foot_point_geoms), bool))
