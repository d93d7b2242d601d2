"""A task names its body (``body = "humanoid3d"``): validated, round-tripped, and absent from a planar task's
definition (its hash is what it was)."""

import pytest

from cmrt.errors import CmrtError
from cmrt.motion.taskfile import load_task, task_from_dict
from cmrt.sim.simulate import simulate


def _stand3d(**extra):
    return {"name": "s3", "body": "humanoid3d", "params": {"clip_s": 2.0, "push_force_y_n": 50.0}, **extra}


def test_a_3d_task_round_trips_and_a_planar_one_has_no_body_key():
    task = task_from_dict(_stand3d())
    assert task.body == "humanoid3d" and task.params["push_force_y_n"] == 50.0
    again = task_from_dict(task.to_dict())
    assert again.body == "humanoid3d" and again.content_hash() == task.content_hash()
    assert "body" not in load_task("stand").to_dict()


@pytest.mark.parametrize("extra, says", [
    ({"body": "robot"}, "body must be one of"),
    ({"end_pose_deg": {"hip": -30.0}}, "a pose-change task needs duration_s > 0"),
    ({"end_pose_deg": {"hip_roll": 10.0}, "params": {"clip_s": 2.0, "duration_s": 0.5}}, "hip_roll"),
    ({"via_pose_deg": {"hip": -30.0}}, "not via_pose_deg"),
    ({"end_pose_deg": {"hip": -30.0}, "params": {"clip_s": 3.0, "duration_s": 0.5, "stance_side": 1.0}},
     "not both"),
    ({"steps": [{"foot": "R", "x_m": 0.2, "duration_s": 0.6}]}, "not steps"),
    ({"params": {"stepping": 1.0}}, "not stepping"),
    ({"prop": {"kind": "wall"}, "end_pose_deg": {"hip": -30.0}, "params": {"clip_s": 3.0, "duration_s": 0.5}},
     "not prop"),
    ({"cmrt_axes": 2}, "not cmrt_axes 2"),  # a standing task takes no CMRT, in one axis or two
    ({"cmrt_axes": 3}, "cmrt_axes must be 1 or 2"),
    ({"cmrt_axes": True}, "cmrt_axes must be 1 or 2"),
    ({"prop": {"kind": "ball"}}, "not prop"),  # a ball is caught by a pose change, not by standing
    ({"prop": {"kind": "ball"}, "end_pose_deg": {"shoulder": -90.0}, "params": {"clip_s": 3.0, "duration_s": 0.5}},
     "ball_balanced = 1"),  # its mass moved into the forearms: not on the 3D body yet
    ({"start_pose_deg": {"knee": 400.0}}, "start_pose_deg"),
])
def test_what_a_3d_task_may_not_say_is_refused(extra, says):
    with pytest.raises(CmrtError, match=says):
        task_from_dict(_stand3d(**extra))


def test_a_cmrt_in_two_axes_is_for_the_3d_body_and_round_trips():
    with pytest.raises(CmrtError, match="cmrt_axes = 2 is for the 3D body"):
        task_from_dict({**load_task("bend").to_dict(), "cmrt_axes": 2})
    task = load_task("punch3d")
    assert task.cmrt_axes == 2 and task.n_cmrt_params == 12
    again = task_from_dict(task.to_dict())
    assert again.cmrt_axes == 2 and again.content_hash() == task.content_hash()
    assert "cmrt_axes" not in load_task("bend3d").to_dict()  # one axis: absent, older hashes stay valid


def test_the_planar_simulator_refuses_a_3d_task():
    with pytest.raises(CmrtError, match="humanoid3d body"):
        simulate(task_from_dict(_stand3d()))
