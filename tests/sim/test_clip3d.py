"""The leg-lift task on the 3D body (cmrt.sim.clip3d): the paper's reactive controller falls toward the lifted side
without a CMRT, the library's CMRT shifts the CoM over the stance foot before lift-off and makes the lift a success
on time; Yu's reference (the reference motion's own weight shift) lifts slowly without a CMRT and falls fast. Each
clip judged by the planar verdict's rules, the timing rule included."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from cmrt.body.character import character
from cmrt.errors import CmrtError
from cmrt.motion.curve import Cmrt
from cmrt.motion.library import library_curve
from cmrt.motion.taskfile import load_task
from cmrt.sim.clip3d import clip_3d, cop_trace
from cmrt.sim.objective import MAX_PLAN_COP_ERROR_M, joint_lags_s
from cmrt.sim.spatial import replay_3d

FAST_S = 2.3  # T of the shipped leg lift (and its library CMRT)


def test_the_fast_lift_falls_sideways_without_a_cmrt_and_succeeds_with_the_librarys():
    task = load_task("leg-lift")
    assert task.speed == FAST_S and task.reference_mode == "center" and task.body == "humanoid3d"
    zero = clip_3d(task, Cmrt.zero(task.clip_s))
    assert zero.fell and zero.failed_rules[0] == "balance" and zero.objective > 5.0
    assert zero.result.fall_time_s > zero.lift.lift_off_s  # after lift-off: its CoM never got over the foot
    assert zero.result.fall_direction_xy[1] < -0.9  # toward the lifted (right, -y) side
    found = clip_3d(task, library_curve(task))
    assert found.success, found.failed_rules
    assert found.timing_lag_s <= found.timing_lag_bound_s and found.result.max_plan_cop_error_m <= MAX_PLAN_COP_ERROR_M
    assert abs(found.lift.foot_lift_m - 0.10) <= 0.01 and found.objective < 5.0
    assert found.lift.com_shift_m > zero.lift.com_shift_m + 0.03  # the anticipation: toward the stance foot first


@pytest.mark.slow  # two 4.5-6 s clips
def test_with_yus_reference_a_slow_lift_needs_no_cmrt_and_a_fast_one_falls():
    task = load_task("leg-lift").with_reference("yu")
    slow = task.with_params(clip_s=6.0, duration_s=4.5)
    assert clip_3d(slow, Cmrt.zero(slow.clip_s)).success
    fast = clip_3d(task, Cmrt.zero(task.clip_s))
    assert fast.fell


def test_the_planar_fast_bend_on_the_3d_body_is_late_without_a_cmrt_and_on_time_slowly():
    """bend3d: the planar bend's reference on the 3D body, judged by the planar rules. At T 0.4 s the reactive
    controller reaches the pose, tracked within its bound, but its trunk is late (as on the planar body: 0.1 s
    against 0.04); at 1.2 s it is a success."""
    fast = clip_3d(load_task("bend3d"), Cmrt.zero(2.6))
    assert not fast.fell and "on_time" in fast.failed_rules and "performed" not in fast.failed_rules
    assert fast.timing_lag_s > 2 * fast.timing_lag_bound_s and fast.final_pose_error_rad < 0.1
    assert fast.tracking_error_rad <= fast.tracking_bound_rad and fast.objective > 5.0
    slow = clip_3d(load_task("bend3d").with_speed(1.2), Cmrt.zero(2.6))
    assert slow.success, slow.failed_rules


def test_same_leg_lift_same_result():
    task = load_task("leg-lift").with_params(duration_s=1.5, clip_s=2.5)
    curve = Cmrt.from_params(np.full(8, 0.3), task.clip_s)
    a, b = clip_3d(task, curve), clip_3d(task, curve)
    assert a.objective == b.objective and np.array_equal(a.result.qpos, b.result.qpos)


def test_a_standing_3d_task_takes_no_cmrt_and_a_lift_is_checked():
    standing = load_task(str(Path(__file__).parents[2] / "docs" / "examples" / "stand3d.toml"))
    with pytest.raises(CmrtError, match="takes no CMRT"):
        clip_3d(standing, Cmrt.from_params(np.ones(8), standing.clip_s))
    for sets, says in (({"stance_side": 0.5}, "stance_side must be"), ({"stance_side": 0}, "moves to lift a foot"),
                       ({"clip_s": 3.0}, "a leg lift needs")):
        with pytest.raises(CmrtError, match=says):
            load_task("leg-lift").with_params(**sets)


def test_the_3d_timing_rule_is_the_planar_ones_joint_rule():
    """``joint_lags_s``: a joint is late by when it covers 90 % of its reference's excursion; a joint that moves
    less than 0.2 rad is not a driving one."""
    t = np.linspace(0.0, 1.0, 101)
    ref = np.stack([np.clip(t, 0, 0.5) * 2.0, 0.1 * t], axis=1)  # 0 -> 1 rad by 0.5 s; a 0.1 rad joint
    late = np.stack([np.clip(t - 0.1, 0, 0.5) * 2.0, np.zeros_like(t)], axis=1)
    lags = joint_lags_s(t, late, ref, [0, 1], t <= 0.6, 0.0)
    assert lags == pytest.approx([0.1])


def test_the_public_simulate_and_evaluate_take_a_3d_task():
    """``cmrt.simulate`` / ``cmrt.evaluate`` on a 3D task: its clip and the planar scoring's record of it, with the
    same verdict and objective as ``cmrt simulate`` prints; a planar task's as before."""
    import cmrt

    task = load_task("leg-lift")
    ev = cmrt.evaluate(task, cmrt.simulate(task, library_curve(task)))
    assert ev.success and ev.performed and not ev.fell and ev.failed_rules == ()
    assert ev.objective == pytest.approx(ev.cop_error_norm + ev.penalty) and ev.penalty == pytest.approx(0.0)
    assert ev.final_pose_error_rad < 0.1 and ev.timing_lag_s <= ev.timing_lag_bound_s
    report = cmrt.evaluation_dict(ev)
    assert report["max_plan_cop_error_m"] == ev.max_plan_cop_error_m and report["success"]
    zero = cmrt.evaluate(task, cmrt.simulate(task))
    assert zero.fell and zero.failed_rules[0] == "balance" and zero.performed is False
    planar = load_task("bend").with_speed(1.2)
    assert cmrt.evaluate(planar, cmrt.simulate(planar, record=False)).success


def test_standing_on_the_right_foot_mirrors_the_left():
    """stance_side -1: the zero CMRT falls toward the lifted (left, +y) side; the library's right-foot CMRT moves the
    CoM toward the right foot before lift-off and succeeds."""
    task = load_task("leg-lift").with_params(stance_side=-1)
    zero = clip_3d(task, Cmrt.zero(task.clip_s))
    assert zero.fell and zero.result.fall_direction_xy[1] > 0.9
    found = clip_3d(task, library_curve(task))
    assert found.success, found.failed_rules
    assert found.lift.com_shift_m > 0.03 and all(v <= 0.0 for v in library_curve(task).values_m[1:3])


def test_a_3d_ensemble_member_pushes_along_the_cmrts_axis_and_scales_the_timing():
    """``perturbed_3d``: a leg lift's member pushes sideways (its CMRT is in y), a pose change's forward (in x), each
    in the member's window; the timing member scales T; a task with a push of its own takes no member's push."""
    from cmrt.motion.ensemble import Perturbation
    from cmrt.sim.clip3d import perturbed_3d

    member = Perturbation(push_force_n=-25.0, push_start_s=1.2, push_duration_s=0.1, time_scale=0.95)
    lift = perturbed_3d(load_task("leg-lift"), member)
    assert (lift.params["push_force_y_n"], lift.params["push_force_n"]) == (-25.0, 0.0)
    assert lift.params["push_start_s"] == 1.2 and lift.params["duration_s"] == pytest.approx(0.95 * 2.3)
    bend = perturbed_3d(load_task("bend3d"), member)
    assert (bend.params["push_force_n"], bend.params["push_force_y_n"]) == (-25.0, 0.0)
    assert perturbed_3d(load_task("leg-lift"), Perturbation()) == load_task("leg-lift")
    pushed = load_task("leg-lift").with_params(push_force_y_n=50.0)
    with pytest.raises(CmrtError, match="pushes of its own"):
        perturbed_3d(pushed, member)


def test_a_robust_3d_candidate_is_scored_on_every_member():
    """The evaluator scores a robust 3D task's candidate as the planar one's: ``ensemble.combine`` of its members'
    clips, a success only if every member is one."""
    from cmrt.motion.ensemble import combine, training_members
    from cmrt.optimize.parallel import evaluate_batch

    task = load_task("bend3d").with_robust()
    curve = library_curve(task)
    (record,) = evaluate_batch(task, [curve.to_params()])
    clips = [clip_3d(task, curve, m) for m in training_members(task, task.robust, False)]
    assert len(clips) > 1 and record.objective == combine([c.objective for c in clips], task.robust)
    assert record.success == all(c.success for c in clips)


def test_the_3d_catch_falls_forward_without_a_cmrt_and_holds_the_ball_with_the_librarys():
    """catch3d: the planar 7 kg catch on the 3D body (``cmrt.sim.prop3d``: the same ball, grip and verdict; its pull
    on the hands known to the 3D plan). The reactive controller grips the ball and falls forward with it; the
    library's CMRT moves the CoM back before the ball arrives and holds it, the plan what happens."""
    task = load_task("catch3d")
    zero = clip_3d(task, Cmrt.zero(task.clip_s))
    caught = zero.prop_figures()
    assert zero.fell and zero.failed_rules[0] == "balance" and caught["task_success"] is False
    assert 1.4 < caught["grip_s"] < 1.5 < zero.result.fall_time_s  # gripped on time, then fell with it
    assert zero.result.fall_direction_xy[0] > 0.9  # forward, toward the ball
    found = clip_3d(task, library_curve(task))
    assert found.success, found.failed_rules
    held = found.prop_figures()
    assert held["task_success"] and held["ball_held_s"] >= task.params["ball_hold_s"]
    assert found.result.max_plan_cop_error_m <= MAX_PLAN_COP_ERROR_M and found.objective < 5.0 < zero.objective
    before = np.searchsorted(found.result.time_s, held["grip_s"]) - 1
    assert found.result.com_m[before, 0] < zero.result.com_m[before, 0] - 0.015  # the anticipation: back first
    # the ball carried in the plan (its inertia known): the arms do not keep turning about their own axes
    yaw = character("humanoid3d").model.joint("shoulder_yaw_r").qposadr[0]
    settled = found.result.time_s >= held["grip_s"] + 0.5
    assert np.abs(found.result.qpos[settled, yaw]).max() < 0.05
    for axis in (0, 1):  # the dashboard's CoP plot of a clip whose qpos carries the ball's too
        trace = cop_trace(task, found, axis)
        assert trace["time_s"].size == found.result.time_s.size and np.isfinite(trace["support_lo_m"]).all()
        assert (trace["support_lo_m"] < 0.0).all() and (trace["support_hi_m"] > 0.0).all()


def test_the_3d_push_is_pushed_back_without_a_cmrt_and_topples_the_slab_with_the_librarys():
    """push3d: the planar push on the 3D body, the 140 kg slab. The reactive controller's hands meet the slab and it
    pushes them back: the body falls backward, the slab stands; the library's CMRT leans into the push and the slab
    goes over, pushed (under ``max_push_force_n``), the body standing."""
    task = load_task("push3d")
    zero = clip_3d(task, Cmrt.zero(task.clip_s))
    assert zero.fell and zero.prop_figures()["task_success"] is False
    assert zero.result.fall_direction_xy[0] < -0.9  # backward, away from the slab
    found = clip_3d(task, library_curve(task))
    assert found.success, found.failed_rules
    pushed = found.prop_figures()
    assert pushed["task_success"] and pushed["peak_contact_force_n"] <= task.params["max_push_force_n"]
    assert found.objective < 5.0 < zero.objective


@pytest.mark.parametrize("name, params", [("catch3d", np.full(8, 0.2)), ("punch3d", np.full(12, 0.1))])
def test_same_prop_task_same_result(name, params):
    """A prop's clip, run twice: the same samples, forces and figures (the punch's CMRT in x and y)."""
    task = load_task(name).with_params(clip_s=2.0)
    curve = Cmrt.from_params(params, task.clip_s)
    a, b = clip_3d(task, curve), clip_3d(task, curve)
    assert a.objective == b.objective and np.array_equal(a.result.qpos, b.result.qpos)
    assert np.array_equal(a.result.prop_force_n, b.result.prop_force_n) and a.prop_figures() == b.prop_figures()


@pytest.mark.parametrize("name", ["catch3d", "push3d", "leg-lift"])  # each falls without a CMRT: a prop's logic
# replayed in Python, a clip without one in compiled code
def test_a_3d_clips_torques_replayed_open_loop_are_the_clip(name):
    """``replay_3d``, the floor ``cmrt bench`` times: the clip's recorded torques, push, prop and protective mode
    stepped again with no controller give the closed-loop CoM at every sample, bit for bit - fall and all."""
    task = load_task(name)
    r = clip_3d(task, Cmrt.zero(task.clip_s)).result
    assert r.fell and r.ctrl_nm.shape == (r.time_s.size, character("humanoid3d").model.nu)
    assert not r.ctrl_nm[r.time_s > r.fall_time_s].any()  # the motors off in protective mode
    com = np.full_like(r.com_m, np.nan)
    assert replay_3d(r, com_out=com) == round(task.clip_s / task.model().opt.timestep)
    assert np.array_equal(com, r.com_m)
    weaker = replace(r, ctrl_nm=r.ctrl_nm * 0.9)  # other torques: another clip (the replay is open loop)
    replay_3d(weaker, com_out=com)
    assert np.abs(com - r.com_m).max() > 0.01


@pytest.mark.parametrize("name", ["bend3d", "leg-lift"])
def test_zero_values_across_leave_a_3d_clip_as_it_was(name):
    """A one-axis CMRT and the same CMRT with zero values across play one clip, bit for bit: the cross axis adds
    exactly nothing, so no one-axis result moves."""
    task = load_task(name)
    one = library_curve(task)
    two = Cmrt(one.clip_s, one.knot_times_s, one.values_m, (0.0,) * 4)
    a, b = clip_3d(task, one), clip_3d(task, two)
    assert two.axes == 2 and a.success
    np.testing.assert_array_equal(a.result.qpos, b.result.qpos)
    assert a.objective == b.objective and a.failed_rules == b.failed_rules


def test_the_cross_axis_moves_the_com_across_the_tasks_own():
    """A two-axis CMRT's cross values displace the CoM's reference across the task's axis - sideways (+y, to the
    left) in a pose change, forward (+x) in a leg lift - and the executed CoM follows, the other axis barely."""
    bend = load_task("bend3d")
    flat = Cmrt.zero(bend.clip_s, 2)
    left = Cmrt(bend.clip_s, flat.knot_times_s, flat.values_m, (0.02,) * 4)
    a, b = clip_3d(bend, flat), clip_3d(bend, left)
    t = a.result.time_s
    plateau = (t > flat.knot_times_s[0]) & (t < flat.knot_times_s[-1])  # the shift is 2 cm between the knots
    dy = b.result.com_m[plateau, 1] - a.result.com_m[plateau, 1]
    dx = b.result.com_m[plateau, 0] - a.result.com_m[plateau, 0]
    assert 0.015 < dy.mean() < 0.03 and np.abs(dx).max() < 0.1 * dy.mean()
    lift = load_task("leg-lift")
    one = library_curve(lift)
    ahead = Cmrt(one.clip_s, one.knot_times_s, one.values_m, (0.02,) * 4)
    c, d = clip_3d(lift, one), clip_3d(lift, ahead)
    before = (c.result.time_s > one.knot_times_s[0]) & (c.result.time_s < c.lift.lift_off_s)
    forward = d.result.com_m[before, 0] - c.result.com_m[before, 0]
    sideways = d.result.com_m[before, 1] - c.result.com_m[before, 1]
    assert forward.mean() > 0.015 and forward.mean() > 10 * np.abs(sideways).mean()


def test_the_planar_body_refuses_a_cmrt_in_two_axes():
    from cmrt.sim.simulate import simulate

    task = load_task("bend")
    with pytest.raises(CmrtError, match="two axes is for the 3D body"):
        simulate(task, Cmrt.zero(task.clip_s, 2))


def test_the_3d_punch_needs_its_cmrt_in_both_axes():
    """punch3d: the planar punch on the 3D body, a 40 kg bag. The reactive controller lands the strike and falls
    backward with the recoil; the library's CMRT in x and y stands through it, its CoM shifted toward the guard side
    (+y) before the launch; the same CMRT's forward values alone stand but break the plan sideways in the launch."""
    task = load_task("punch3d")
    assert task.cmrt_axes == 2
    zero = clip_3d(task, Cmrt.zero(task.clip_s, 2))
    assert zero.fell and zero.result.fall_direction_xy[0] < -0.9 and zero.prop_figures()["task_success"]
    lib = library_curve(task)
    found = clip_3d(task, lib)
    assert lib.axes == 2 and found.success, found.failed_rules
    struck = found.prop_figures()
    assert struck["fist_speed_at_contact_m_s"] >= task.params["min_fist_speed_m_s"]
    launch = int(np.searchsorted(found.result.time_s, task.preparation_s))
    assert found.result.com_m[launch, 1] - zero.result.com_m[launch, 1] > 0.005  # toward the left, the guard's side
    forward = clip_3d(task, lib.along())
    assert not forward.fell and forward.failed_rules == ("plan",)
    assert found.result.max_plan_cop_error_m <= MAX_PLAN_COP_ERROR_M < forward.result.max_plan_cop_error_m



def test_a_joint_ending_at_its_stop_is_timed_as_the_controller_holds_it():
    """rise3d ends with straight knees, at their 0 rad stop; the 3D controller, as the planar one, holds every joint
    ``stop_margin_rad`` inside its stops, and the timing rule judges against that reference (``reachable``, the
    planar rule's): judged against the stop itself the knee was never done and the zero CMRT's rise read 0.76 s
    late, which no CMRT could mend."""
    from cmrt.control.controller import ControllerConfig
    from cmrt.sim.objective import reachable

    m = character("humanoid3d").model
    knee = int(m.jnt_qposadr[m.joint("knee_r").id])
    assert reachable(np.zeros((1, m.nq)), "humanoid3d")[0, knee] == pytest.approx(ControllerConfig.stop_margin_rad)
    task = load_task("rise3d")
    zero = clip_3d(task, Cmrt.zero(task.clip_s))
    assert zero.failed_rules == ("on_time",) and 0.04 < zero.timing_lag_s < 0.1  # the trunk, as on the planar body
    lib = clip_3d(task, library_curve(task))
    assert lib.success and lib.timing_lag_s <= lib.timing_lag_bound_s
