"""The paper's tasks on the contact-consistent controller: where anticipation matters (ABC section 5),
and determinism per task."""

import pytest

from cmrt import evaluate, library_curve, load_task, simulate

HARD = [("bend", {"duration_s": 0.4}), ("rise", {"duration_s": 0.5}), ("punch", {}), ("push", {})]


@pytest.mark.parametrize("name, overrides", HARD, ids=[h[0] for h in HARD])
def test_zero_cmrt_fails_and_library_cmrt_succeeds(name, overrides):
    task = load_task(name).with_params(**overrides)
    zero = evaluate(task, simulate(task, record=False))
    lib = evaluate(task, simulate(task, library_curve(task), record=False))
    assert not zero.success and (zero.fell or zero.performed is False)
    assert lib.success and not lib.fell
    assert lib.task_success in (True, None) and (lib.task_success is True) == task.has_goal
    assert lib.objective <= 0.5 * zero.objective
    if not task.has_goal:  # with a prop the pose may be blocked on purpose (the fist stops at the pad)
        assert lib.final_pose_error_rad < 0.1


def test_catch_needs_no_anticipation_on_this_controller_but_gains_from_it():
    """Measured: the 7 kg ball flying level at 4 m/s is caught by the reactive controller alone; the
    library CMRT keeps the CoP nearer the middle of the feet."""
    task = load_task("catch")
    zero = evaluate(task, simulate(task, record=False))
    lib = evaluate(task, simulate(task, library_curve(task), record=False))
    assert zero.success and lib.success
    assert lib.objective < 0.6 * zero.objective


def test_slow_bend_library_beats_zero():
    task = load_task("bend").with_speed(1.2)
    zero = evaluate(task, simulate(task, record=False))
    lib = evaluate(task, simulate(task, library_curve(task), record=False))
    assert zero.success and lib.success
    assert lib.objective < zero.objective


@pytest.mark.parametrize("name", ["stand", "bend", "rise", "punch", "catch", "push"])
def test_determinism_per_task(name):
    task = load_task(name)
    if name == "stand":
        task = task.with_params(clip_s=3.0, push_force_n=120.0)
    a = evaluate(task, simulate(task, record=False))
    b = evaluate(task, simulate(task, record=False))
    assert a == b


def test_expectation_mismatch_light_ball():
    """ABC 5: the CMRT optimized for a 7 kg ball, used on a 1 kg ball, is much worse (measured: balance
    still kept on this controller; the anticipatory lean is now unopposed)."""
    heavy = load_task("catch")
    curve = library_curve(heavy)
    expected = evaluate(heavy, simulate(heavy, curve, record=False))
    light = heavy.with_params(ball_mass_kg=1.0)
    surprised = evaluate(light, simulate(light, curve, record=False))
    assert expected.success
    assert surprised.fell or surprised.objective >= 2.0 * expected.objective


def test_goals_can_be_missed_and_are_penalised():
    task = load_task("catch").with_params(ball_height_m=2.6)  # thrown over the head
    ev = evaluate(task, simulate(task, record=False))
    assert ev.task_success is False and ev.objective >= 30.0 and not ev.success
    pose = evaluate(load_task("bend").with_speed(1.2), simulate(load_task("bend").with_speed(1.2), record=False))
    assert pose.task_success is None
