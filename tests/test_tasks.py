"""The paper's tasks on the contact-consistent controller: where anticipation matters (ABC section 5),
and determinism per task."""

import pytest

from cmrt import evaluate, library_curve, load_task, simulate

HARD = [("bend", {"duration_s": 0.4}), ("rise", {"duration_s": 0.5}), ("catch", {}), ("push", {})]


@pytest.mark.parametrize("name, overrides", HARD, ids=[h[0] for h in HARD])
def test_zero_cmrt_fails_and_library_cmrt_succeeds(name, overrides):
    task = load_task(name).with_params(**overrides)
    zero = evaluate(task, simulate(task, record=False))
    lib = evaluate(task, simulate(task, library_curve(task), record=False))
    assert not zero.success and (zero.fell or zero.performed is False)
    assert lib.success and not lib.fell
    assert lib.task_success in (True, None) and (lib.task_success is True) == task.has_goal
    assert lib.objective <= 0.5 * zero.objective
    if not task.has_goal:
        assert lib.final_pose_error_rad < 0.1


def test_punch_needs_no_anticipation_but_the_library_improves_it():
    """Measured: the strike-and-retract punch succeeds with the reactive controller alone; the
    library CMRT keeps the CoP nearer the middle of the feet."""
    task = load_task("punch")
    zero = evaluate(task, simulate(task, record=False))
    lib = evaluate(task, simulate(task, library_curve(task), record=False))
    assert zero.success and lib.success and lib.objective < zero.objective


def test_the_papers_7kg_ball_is_caught_without_anticipation():
    """Measured: on this character the weight of 7 kg at arm's length moves the CoP about 7 cm of the
    ~10 cm it has in front; the task ships with 12 kg, which tips it forwards (README)."""
    task = load_task("catch").with_params(ball_mass_kg=7.0)
    assert evaluate(task, simulate(task, record=False)).success


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
    """ABC 5: the CMRT optimized for the heavy ball, used on a 1 kg ball, does worse than no
    anticipation at all (measured: 3x the objective; balance is kept - the paper's character falls)."""
    heavy = load_task("catch")
    curve = library_curve(heavy)
    expected = evaluate(heavy, simulate(heavy, curve, record=False))
    light = heavy.with_params(ball_mass_kg=1.0)
    surprised = evaluate(light, simulate(light, curve, record=False))
    unprepared = evaluate(light, simulate(light, record=False))
    assert expected.success
    assert surprised.fell or surprised.objective >= 2.0 * unprepared.objective


def test_goals_can_be_missed_and_are_penalised():
    task = load_task("catch").with_params(ball_height_m=2.6)  # thrown over the head
    ev = evaluate(task, simulate(task, record=False))
    assert ev.task_success is False and ev.objective >= 30.0 and not ev.success
    pose = evaluate(load_task("bend").with_speed(1.2), simulate(load_task("bend").with_speed(1.2), record=False))
    assert pose.task_success is None
