"""The support's field (cmrt.body.surface) against the physics it stands for, and its parameters."""

import math

import mujoco
import numpy as np
import pytest

from cmrt.body.props import build_model
from cmrt.body.surface import SURFACE_PARAMS, Support, body_inertia_yy, tilt_pose
from cmrt.errors import CmrtError
from cmrt.motion.task import active_params
from cmrt.motion.taskfile import load_task

# A free planar block (slide x, slide z, hinge y), no contact: in the world it flies a parabola and spins at a
# constant rate, so its motion seen from a turning, moving frame is known exactly.
BLOCK = """
<mujoco>
  <option timestep="0.0005" integrator="RK4" gravity="0 0 -9.81"/>
  <worldbody>
    <body name="block" pos="0 0 0">
      <joint name="x" type="slide" axis="1 0 0"/>
      <joint name="z" type="slide" axis="0 0 1"/>
      <joint name="pitch" type="hinge" axis="0 1 0"/>
      <geom type="box" size="0.2 0.1 0.05" mass="3" contype="0" conaffinity="0" pos="0.1 0 0.03"/>
    </body>
  </worldbody>
</mujoco>
"""


def _rot(theta):
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, s], [-s, c]])  # support -> world (x, z), a turn of theta about +y


def _fly(support: Support, timestep_s: float) -> tuple[float, float]:
    """The block flown for 0.8 s in the support's frame from t = 0.3 s (inside the fade-in: the envelope's
    derivatives enter too): how far its CoM and angle end from its exact world motion seen from the frame."""
    m = mujoco.MjModel.from_xml_string(BLOCK)
    m.opt.timestep = timestep_s
    d = mujoco.MjData(m)
    body = m.body("block").id
    t0 = 0.3
    p0_w, v0_w, spin = np.array([0.4, 1.2]), np.array([0.5, 1.0]), 2.0  # the CoM's world motion
    theta0, omega0, _ = (float(v) for v in support.tilt(t0))
    o_pos, _ = support.origin(t0)
    o_vel = (support.origin(t0 + 1e-6)[0] - support.origin(t0 - 1e-6)[0]) / 2e-6
    R = _rot(theta0)
    # seen from the frame: x = R^T (X - O), v = R^T (V - O') - omega x (omega x (x, z) = (omega z, -omega x))
    x0 = R.T @ (p0_w - o_pos)
    v0 = R.T @ (v0_w - o_vel) - omega0 * np.array([x0[1], -x0[0]])
    mujoco.mj_forward(m, d)
    lever = d.xipos[body, [0, 2]] - d.xpos[body, [0, 2]]  # the CoM sits off the joints' origin (pitch 0)
    d.qpos[:] = [*(x0 - lever), 0.0]
    w_rel = spin - omega0  # a body's angle in the frame is its world angle less theta (both about +y)
    d.qvel[:] = [v0[0] - w_rel * lever[1], v0[1] + w_rel * lever[0], w_rel]  # v_com = v_joint + w x lever
    mass = m.body_mass
    t = t0
    for _ in range(int(round(0.8 / timestep_s))):
        mujoco.mj_forward(m, d)
        inertia = body_inertia_yy(m, d)
        r = d.xipos - d.subtree_com[m.body_rootid]
        vel = np.stack([d.cvel[:, 3] + d.cvel[:, 1] * r[:, 2], d.cvel[:, 5] - d.cvel[:, 1] * r[:, 0]], axis=-1)
        f = support.field(t, d.xipos[None, :, [0, 2]], vel[None], mass, inertia)[0]
        d.xfrc_applied[:, 0], d.xfrc_applied[:, 2], d.xfrc_applied[:, 4] = f[:, 0], f[:, 1], f[:, 2]
        mujoco.mj_step(m, d)
        t += timestep_s
    mujoco.mj_forward(m, d)
    T = t - t0
    p_w = p0_w + v0_w * T + 0.5 * np.array([0.0, -9.81]) * T * T
    theta = float(support.tilt(t)[0])
    expected = _rot(theta).T @ (p_w - support.origin(t)[0])
    # the world angle grows at the constant spin; the frame's angle is it less the frame's turn
    return (float(np.linalg.norm(d.xipos[body, [0, 2]] - expected)),
            abs(float(d.qpos[2]) - (spin * T - (theta - theta0))))


@pytest.mark.parametrize("support", [
    Support(slope_deg=15.0),
    Support(tilt_amplitude_deg=20.0, tilt_period_s=2.0),
    Support(sway_amplitude_m=0.1, sway_period_s=1.0, heave_amplitude_m=0.05, heave_period_s=0.7),
    Support(slope_deg=-5.0, tilt_amplitude_deg=10.0, tilt_period_s=1.5, sway_amplitude_m=0.05, sway_period_s=0.8),
], ids=["slope", "shaking", "moving", "all"])
def test_the_field_moves_a_free_body_as_the_frame_sees_its_world_motion(support):
    """Integrated in the support's frame with ``Support.field`` as xfrc_applied (held over each step, as the
    simulation does), a free block's CoM and angle converge to its exact world motion - a parabola and a constant
    spin - seen from the frame: gravity, the frame's acceleration, the centrifugal, Euler and Coriolis terms and
    the Euler torque all enter, each with its sign. A wrong term leaves an error that does not shrink with the
    step (a sign flip of any: centimetres)."""
    coarse = _fly(support, 5e-4)
    fine = _fly(support, 1.25e-4)
    for c, f in zip(coarse, fine, strict=True):
        assert f < 2e-4
        assert f <= 0.3 * c + 1e-7  # first order in the step: a quarter of the step, a quarter of the error


def test_a_still_level_floor_has_no_field_and_keeps_every_hash():
    """Every surface parameter at its default adds nothing: no field, the model of before, the content hashes of
    before (runs and library entries are keyed by them)."""
    assert Support().still_and_level and Support(floor_friction=0.5).still_and_level
    task = load_task("bend")
    assert all(task.params[k] == v for k, v in SURFACE_PARAMS.items())
    assert not set(SURFACE_PARAMS) & set(active_params(task.params))
    assert task.content_hash() == task.with_params(slope_deg=0.0, floor_friction=1.0).content_hash()
    assert task.content_hash() != task.with_params(slope_deg=5.0).content_hash()
    assert task.model() is build_model(None, ())  # the same compiled model object (cached)


def test_the_floor_friction_is_the_floors():
    """With a floor friction set, MuJoCo's contact takes the floor's (its priority), not the larger of two."""
    m = load_task("stand").with_params(floor_friction=0.08).model()
    floor = m.geom("floor").id
    assert m.geom_friction[floor, 0] == pytest.approx(0.08) and m.geom_priority[floor] > 0


def test_the_feet_keep_their_heel_pad_on_a_floor_of_another_friction():
    """Priority hands the floor every contact parameter, solref too: the floor carries the heel pad's contact (the
    0.015 s the feet have on the default floor), so a slippery floor is slippery, not also stiffer."""
    for friction in (1.0, 0.08, 1.5):
        m = load_task("stand").with_params(floor_friction=friction).model()
        d = mujoco.MjData(m)
        d.qpos[:] = load_task("stand").start_qpos()
        d.qpos[1] -= 0.002  # every foot point 2 mm into the floor
        mujoco.mj_forward(m, d)
        feet = [c for c in d.contact[: d.ncon] if m.geom("floor").id in c.geom]
        assert len(feet) == 4 and all(np.allclose(c.solref, [0.015, 1.0]) for c in feet), friction
        assert all(c.friction[0] == pytest.approx(friction) for c in feet)


@pytest.mark.parametrize("key,value", [("slope_deg", 40), ("floor_friction", 0), ("tilt_period_s", 0.1),
                                       ("tilt_amplitude_deg", -5), ("sway_amplitude_m", 2)])
def test_surface_parameters_out_of_range_are_refused(key, value):
    with pytest.raises(CmrtError, match=key):
        load_task("stand").with_params(**{key: value})


@pytest.mark.parametrize("task,params,match", [
    ("stand", {"box_stiffness_n_m": 20000.0}, "set box_mass_kg > 0 too"),
    ("stand", {"box_mass_kg": 200.0, "slope_deg": 5.0}, "slope_deg cannot be set with box_mass_kg"),
    ("catch", {"box_mass_kg": 200.0}, "carries the character alone"),
    ("stand", {"box_mass_kg": -1.0}, "box_mass_kg"),
    ("stand", {"box_mass_kg": 200.0, "box_stiffness_n_m": 10.0}, "box_stiffness_n_m"),
])
def test_floating_box_parameters_that_cannot_be_simulated_are_refused(task, params, match):
    with pytest.raises(CmrtError, match=match):
        load_task(task).with_params(**params)


def test_the_cli_refuses_a_floating_box_under_a_prop_in_one_line(tmp_path):
    from tests.service_helpers import cmrt

    out = cmrt("submit", "catch", "--set", "box_mass_kg=200", store=tmp_path / "s.sqlite")
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert not (tmp_path / "s.sqlite").exists()


def test_tilt_pose_keeps_the_feet_and_stands_upright():
    """On a support tilted by theta the start pose turns by -theta above the ankles: the feet stay put."""
    task = load_task("stand")
    m = task.model()
    q = task.start_qpos()
    d0, d1 = mujoco.MjData(m), mujoco.MjData(m)
    d0.qpos[: q.size] = q
    d1.qpos[: q.size] = tilt_pose(m, q, -0.26)
    mujoco.mj_kinematics(m, d0)
    mujoco.mj_kinematics(m, d1)
    feet = [m.geom(n).id for n in ("heel_r", "toe_r", "heel_l", "toe_l")]
    assert np.allclose(d0.geom_xpos[feet], d1.geom_xpos[feet], atol=1e-9)
    assert d1.qpos[2] - d0.qpos[2] == pytest.approx(0.26)
