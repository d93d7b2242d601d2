"""Behaviour of the reactive controller on the foundation tasks: successes, topples, determinism."""

import numpy as np
import pytest

from cmrt import Cmrt, evaluate, library_curve, load_task, simulate
from cmrt.sim.balance import FallReason
from cmrt.sim.simulate import POST_FALL_S, simulate_batch

# What a researcher would accept as plausible motion before any fall (issue: physically credible balance).
MAX_AIRBORNE_S = 0.01
MAX_PEAK_FORCE_BW = 2.5
MAX_JOINT_SPEED_RAD_S = 25.0


def assert_plausible(ev):
    assert ev.airborne_s <= MAX_AIRBORNE_S, ev
    assert ev.peak_normal_force_bw <= MAX_PEAK_FORCE_BW, ev
    assert ev.max_joint_speed_rad_s <= MAX_JOINT_SPEED_RAD_S, ev


@pytest.fixture(scope="module")
def stand():
    return load_task("stand")


@pytest.mark.slow  # a 10 s clip (stand is in the fast loop through tests/motion/test_tasks.py)
def test_quiet_standing_ten_seconds(stand):
    traj = simulate(stand)
    ev = evaluate(stand, traj)
    assert ev.success and ev.settled and ev.performed is None
    assert ev.final_com_speed_m_s < 0.01
    assert abs(traj.cop_x_m[-2] - traj.support_center_x_m[-2]) < 0.01
    assert_plausible(ev)


@pytest.mark.slow  # 10 s clips
@pytest.mark.parametrize("force_n", [100.0, -100.0])
def test_push_is_recovered_and_the_character_settles(stand, force_n):
    task = stand.with_params(push_force_n=force_n, push_start_s=2.0, push_duration_s=0.1)
    traj = simulate(task)
    ev = evaluate(task, traj)
    assert ev.success and not ev.fell
    moved = np.abs(traj.cop_x_m - traj.support_center_x_m)
    assert np.nanmax(moved[(traj.time_s > 2.0) & (traj.time_s < 2.5)]) > 0.02  # the push was felt
    after = traj.time_s >= 2.1 + 2.0
    assert np.nanmax(moved[after]) < 0.01
    assert_plausible(ev)


@pytest.mark.slow  # two 10 s clips recorded through the topple
@pytest.mark.parametrize("force_n", [250.0, -250.0])
def test_strong_push_topples_instead_of_launching(stand, force_n):
    """250 N for 0.1 s is a loss of balance: detected before the body is on its way down, then a topple
    played out in protective mode that never lifts the CoM - no flight, no back-flip."""
    task = stand.with_params(push_force_n=force_n, push_start_s=2.0, push_duration_s=0.1, clip_s=4.0)
    traj = simulate(task)
    ev = evaluate(task, traj)
    assert ev.fell and not ev.success and ev.objective > 10.0
    assert ev.fall_reason == FallReason.CAPTURE_POINT.value
    k = int(np.searchsorted(traj.time_s, traj.fall_time_s))
    assert traj.com_m[k, 1] > 0.9  # still upright when the fall is declared: not already launched or down
    assert traj.time_s[-1] >= traj.fall_time_s + POST_FALL_S - 1e-9
    assert np.nanmax(traj.com_m[k:, 1]) <= traj.com_m[k, 1] + 0.05
    # it went down, toward the push, onto the floor: the protective mode's tone lets the legs fold, so a
    # backward fall ends sitting (CoM 0.42 m) where a body held stiff fell flat like a plank (0.12 m)
    assert ev.after_fall_floor_contact_s is not None and traj.com_m[-1, 1] < 0.5
    assert np.sign(traj.com_m[-1, 0] - traj.com_m[k, 0]) == np.sign(force_n)
    assert_plausible(ev)


def test_slow_bend_is_a_success():
    task = load_task("bend").with_speed(1.2)
    ev = evaluate(task, simulate(task))
    assert ev.success and ev.performed and ev.settled
    assert ev.final_pose_error_rad < 0.1 and ev.tracking_error_rad <= ev.tracking_bound_rad
    assert_plausible(ev)


def test_fast_bend_is_not_a_success_without_anticipation():
    task = load_task("bend").with_speed(0.4)
    ev = evaluate(task, simulate(task))
    assert not ev.success
    assert ev.fell or ev.performed is False
    assert_plausible(ev)


@pytest.mark.slow  # covered fast by test_tasks determinism and the warm-start tests
def test_library_cmrt_makes_the_fast_bend_a_success():
    task = load_task("bend").with_speed(0.4)
    zero = evaluate(task, simulate(task))
    lib = evaluate(task, simulate(task, library_curve(task)))
    assert lib.success and not zero.success
    assert lib.final_pose_error_rad < 0.1
    assert lib.objective < zero.objective
    assert_plausible(lib)


def test_same_task_and_curve_give_bit_identical_objectives():
    task = load_task("bend").with_speed(0.5)
    curve = Cmrt.from_params(np.array([0.3, 0.5, -0.2, 0.1, 0.2, -0.1, 0.0, 0.3]), task.clip_s)
    a = evaluate(task, simulate(task, curve))
    b = evaluate(task, simulate(task, curve))
    assert a.objective == b.objective
    assert a == b


def test_absurd_cmrt_is_a_penalty_not_an_exception():
    """A CMRT moving the CoM target metres away is penalised as a fall; nothing raises."""
    task = load_task("bend").with_speed(1.2)
    curve = Cmrt(task.clip_s, (0.5, 1.0, 1.5, 2.0), (3.0, -3.0, 3.0, -3.0))
    ev = evaluate(task, simulate(task, curve))
    assert ev.fell and ev.objective >= 10.0 and not ev.success


def test_batched_clips_equal_clips_alone_and_falls_do_not_poison_the_batch():
    """A generation stepped in lockstep scores exactly as each candidate alone, including candidates
    that fall early (they are stopped and masked out of the batch)."""
    task = load_task("bend").with_speed(0.4)
    base = library_curve(task).to_params()
    rng = np.random.default_rng(3)
    curves = [Cmrt.from_params(base + rng.normal(0, scale, 8), task.clip_s) for scale in (0, 0.02, 0.05, 0.4, 0.4)]
    curves.append(Cmrt(task.clip_s, (0.5, 1.0, 1.5, 2.0), (3.0, -3.0, 3.0, -3.0)))  # absurd: falls early
    curves.append(None)  # zero CMRT
    together = [evaluate(task, t) for t in simulate_batch(task, curves)]
    alone = [evaluate(task, simulate_batch(task, [c])[0]) for c in curves]
    assert any(e.fell for e in together) and any(e.success for e in together)
    for a, b in zip(together, alone, strict=True):
        assert a == b


@pytest.mark.slow  # two recorded clips
def test_recording_a_trace_does_not_change_the_score():
    task = load_task("bend").with_speed(0.5)
    curve = library_curve(task.with_speed(0.4))
    # the same score; a trace adds figures only it has (objective.TRACE_ONLY_FIELDS)
    recorded = evaluate(task, simulate(task, curve, record=True))
    assert recorded.scored() == evaluate(task, simulate(task, curve, record=False)).scored()
    assert recorded.max_plan_cop_error_m is not None
    falling = load_task("stand").with_params(push_force_n=250.0, push_duration_s=0.1, clip_s=3.0)
    recorded = evaluate(falling, simulate(falling, record=True))
    assert recorded.scored() == evaluate(falling, simulate(falling, record=False)).scored()
    assert recorded.after_fall_max_joint_speed_rad_s is not None and recorded.fall_direction_source == "topple"


def test_a_trace_covers_the_clip_and_its_standing_tail():
    task = load_task("bend").with_speed(1.2)
    traj = simulate(task)
    assert traj.time_s.size == round((task.clip_s + task.tail_s) / 0.002)
    assert np.all(np.isfinite(traj.qpos)) and np.all(np.isfinite(traj.foot_roll_rad))
    assert np.all(traj.cmrt_displacement_m[traj.time_s > task.clip_s] == 0.0)


def test_compiled_control_step_geometry_equals_the_numpy_it_replaced():
    """``_Geometry.at_control`` (one compiled pass per control step) against the numpy expressions the
    loop used before, bit for bit, on random states with NaNs (a diverged row) and feet off the floor."""
    from cmrt.body.character import character
    from cmrt.sim.simulate import _Geometry, _ground_support, _in_contact

    geo, m = _Geometry(), character().model
    act = np.array(character().actuated_dofs)
    rng = np.random.default_rng(3)
    n = 40
    geom_xpos = rng.normal(0.0, 0.3, (n, m.ngeom, 3))
    geom_xpos[:, geo.points, 2] = rng.choice([0.0, 0.01, 0.05], (n, geo.points.size))  # some touch, some do not
    geom_xmat = rng.normal(0.0, 1.0, (n, m.ngeom, 9))
    qpos, qvel = rng.normal(0.0, 1.0, (n, m.nq)), rng.normal(0.0, 5.0, (n, m.nv))
    geom_xpos[3, geo.points[1], 0] = geom_xpos[5, geo.body_geoms[2], 2] = np.nan
    qvel[7, act[3]] = qpos[9, geo.leg_dofs[1, 1]] = np.nan
    geom_xpos[11, geo.points, 2] = 1.0  # airborne
    point_x, lo, hi, contact, roll, jspeed, lowest, grounded, c_lo, c_hi = geo.at_control(
        geom_xpos, geom_xmat, qpos, qvel, act)
    want_x = geom_xpos[:, geo.points, 0]
    want_contact = _in_contact(geom_xpos, geo.points)
    want_grounded, want_lo, want_hi = _ground_support(want_contact, want_x)
    for got, want in ((point_x, want_x), (lo, want_x.min(axis=1)), (hi, want_x.max(axis=1)),
                      (contact, want_contact), (roll, geo.foot_roll(qpos)),
                      (jspeed, np.abs(qvel[:, act]).max(axis=1)), (lowest, geo.lowest_body_z(geom_xpos, geom_xmat)),
                      (grounded, want_grounded), (c_lo, want_lo), (c_hi, want_hi)):
        assert np.array_equal(got, want, equal_nan=got.dtype.kind == "f")
