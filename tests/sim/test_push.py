"""The push (ABC 5, domino push): a 140 kg slab driven over in T = 0.35 s; without anticipation the shove's reaction
knocks the character backward, with a CMRT that brings the CoM forward into the push the slab goes over and the
character stands (docs/controller.md, *Push*)."""

import mujoco
import numpy as np
import pytest

from cmrt import evaluate, load_task, simulate
from cmrt.body.props import FOREARM_RADIUS_M, HAND_OFFSET_M, MAX_PUSH_FORCE_N, Prop, Slab, prop_class
from cmrt.motion.curve import Cmrt
from cmrt.sim.objective import MAX_PLAN_COP_ERROR_M
from tests.sim.test_simulate import assert_plausible

# Found by `cmrt optimize push --init none --seed 2 --max-evals 2000` (rounded to 0.1 mm and 0.1 ms): the CoM target
# rises 1 cm by the time the hands reach the slab and 6 cm during the drive (docs/controller.md, *Push*).
LEAN_INTO_THE_PUSH = Cmrt(3.0, (0.6136, 0.8678, 1.3770, 1.9445), (0.0075, 0.0128, 0.0514, 0.0252))  # seed 1, 1500 evals


@pytest.fixture(scope="module")
def push():
    return load_task("push")


@pytest.fixture(scope="module")
def lean(push):
    return evaluate(push, simulate(push, LEAN_INTO_THE_PUSH))


def hand_front_x(task, qpos) -> float:
    """The most forward point of the right forearm (hand included) in pose ``qpos``."""
    m = task.model()
    d = mujoco.MjData(m)
    d.qpos[: qpos.size] = qpos
    mujoco.mj_kinematics(m, d)
    body = m.body("forearm_r").id
    elbow, tip = d.xpos[body], d.xpos[body] + d.xmat[body].reshape(3, 3) @ HAND_OFFSET_M
    return float(max(elbow[0], tip[0]) + FOREARM_RADIUS_M)


def test_the_paper_push_starts_with_the_hands_clear_of_the_slab(push):
    """ABC's 140 kg and T = 0.35 s; the hands start 19 cm from the slab's face (a push, not a lean), and the slab is
    free to slide and tip."""
    assert push.duration_s == 0.35 and push.params["slab_mass_kg"] == 140.0
    assert push.params["max_push_force_n"] == MAX_PUSH_FORCE_N == 1000.0
    m = push.model()
    assert [m.joint(j).name for j in range(m.njnt) if m.joint(j).name.startswith("slab")] == [
        "slab_x", "slab_z", "slab_pitch"]
    gap = push.params["slab_x_m"] - hand_front_x(push, push.start_qpos())
    assert gap >= 0.05, gap


def test_without_anticipation_the_push_knocks_the_character_backward(push):
    """Zero CMRT: the hands meet the slab mid-drive and shove it (~27 N s in 40 ms), too briefly to topple it; the
    reaction drives the CoM backward, its capture point passes the CoP's reach at the heels and the character falls
    backward."""
    ev = evaluate(push, simulate(push))
    assert not ev.success and ev.task_success is False
    assert ev.fell and ev.fall_direction == "backward" and "balance" in ev.failed_rules
    start, stop = push.task_window_s()
    assert start <= ev.first_contact_s <= stop


def test_a_cmrt_that_leans_into_the_push_topples_the_slab_on_time(push, lean):
    """The CMRT brings the CoM forward as the hands reach the slab: a push (peak force under 1,000 N), done on time,
    the slab over, every rule of the verdict met."""
    assert lean.success and lean.failed_rules == () and lean.task_success
    assert lean.peak_contact_force_n <= MAX_PUSH_FORCE_N
    assert lean.timing_lag_s <= lean.timing_lag_bound_s
    assert lean.max_plan_cop_error_m <= MAX_PLAN_COP_ERROR_M
    start, stop = push.task_window_s()
    assert start <= lean.first_contact_s <= stop
    assert_plausible(lean)


def test_the_arms_push_because_the_controller_feels_the_slab(push, lean, monkeypatch):
    """Without the slab's measured push-back in the plan, the tracked arms fold under it like springs: the same CMRT
    is late by half a second and the slab stays up."""
    monkeypatch.setattr(Slab, "hand_load", Prop.hand_load)
    blind = evaluate(push, simulate(push, LEAN_INTO_THE_PUSH))
    assert lean.success and not blind.success
    assert "on_time" in blind.failed_rules and blind.timing_lag_s > 0.3 and blind.task_success is False


def test_the_slab_load_is_what_the_forearms_feel(push):
    """Slab.hand_load is minus the contact force (normal and friction) the forearms put on the slab, as MuJoCo's
    own contact forces give it, acting where they touch."""
    m = push.model()
    d = mujoco.MjData(m)
    d.qpos[: push.start_qpos().size] = push.start_qpos()
    mujoco.mj_kinematics(m, d)
    d.qpos[m.joint("slab_x").qposadr[0]] = hand_front_x(push, push.start_qpos()) - 0.005 - push.params["slab_x_m"]
    mujoco.mj_forward(m, d)
    expected, points = np.zeros(3), []
    for i in range(d.ncon):
        c = d.contact[i]
        if "slab" in (m.geom(c.geom1).name, m.geom(c.geom2).name):
            f = np.zeros(6)
            mujoco.mj_contactForce(m, d, i, f)
            on_slab = c.frame.reshape(3, 3).T @ f[:3] * (1.0 if m.geom(c.geom2).name == "slab" else -1.0)
            expected += on_slab
            points.append(c.pos.copy())
    assert len(points) == 2 and expected[0] > 10.0  # both forearms press on it
    prop = prop_class("slab")(m, push.params)
    b = {"sensordata": d.sensordata[None], "xpos": d.xpos[None]}
    force, point, bodies = prop.hand_load(b, np.array([0]))
    np.testing.assert_allclose(force[0], -expected[[0, 2]], rtol=1e-6)
    np.testing.assert_allclose(point[0, [0, 2]], np.mean(points, axis=0)[[0, 2]], atol=1e-9)
    assert [m.body(i).name for i in bodies] == ["forearm_r", "forearm_l"]


def test_a_slab_struck_harder_than_a_push_is_not_pushed(push):
    """Toppled counts only as a push: first touched inside the task window and never struck above max_push_force_n."""
    prop = prop_class("slab")(push.model(), push.params)
    times = np.arange(0.0, 2.0, 0.01)
    b = {"qpos": np.zeros((3, push.model().nq))}
    b["qpos"][:, prop.pitch] = np.radians(40.0)  # all three toppled
    force = np.zeros((3, times.size))
    force[:, (times > 1.1) & (times < 1.3)] = 400.0  # pushed inside [1.0, 1.35]
    force[1, 12] = 1200.0  # ... and struck
    force[2, (times > 0.5) & (times < 1.0)] = 100.0  # leaning on it before the window
    assert prop.success(b, np.arange(3), force, times, (1.0, 1.35)).tolist() == [True, False, False]
