import numpy as np
import pytest

from cmrt.optimize.driver import (
    CmaState,
    EvalRecord,
    OptimizeSettings,
    new_state,
    popsize_of,
    restart_if_stalled,
    step,
    stop_reason,
)
from tests.optimize.toy_objectives import rugged, sphere


def run(settings, n_gen, state=None):
    state = state or new_state(settings)
    for _ in range(n_gen):
        step(state, sphere)
    return state


def test_seeded_runs_are_identical_and_leave_global_rng_alone():
    np.random.seed(123)
    before = np.random.get_state()[1].copy()
    a = run(OptimizeSettings(seed=5), 6)
    b = run(OptimizeSettings(seed=5), 6)
    c = run(OptimizeSettings(seed=6), 6)
    assert np.array_equal(a.best_x, b.best_x) and a.best_objective == b.best_objective
    assert not np.array_equal(a.best_x, c.best_x)
    assert np.array_equal(np.random.get_state()[1], before)


def test_checkpoint_resume_is_bit_identical():
    settings = OptimizeSettings(seed=2)
    straight = run(settings, 8)
    half = run(settings, 3)
    resumed = run(settings, 5, CmaState.loads(half.dumps()))
    assert np.array_equal(straight.best_x, resumed.best_x)
    assert straight.best_history == resumed.best_history
    assert np.array_equal(straight.es.mean, resumed.es.mean)


def test_stop_rules():
    s = OptimizeSettings(seed=1, stop_threshold=0.05, max_evals=10_000, min_evals=700)
    state = new_state(s)
    while (reason := stop_reason(state, s)) is None:
        step(state, sphere)
    assert reason == "threshold" and state.best_objective < 0.05
    budget = OptimizeSettings(seed=1, max_evals=30)
    state = new_state(budget)
    while stop_reason(state, budget) is None:
        step(state, sphere)
    assert stop_reason(state, budget) == "budget" and state.evaluations == 30
    # a flat objective that never succeeds: stalls restart with a growing population until restarts run out
    # (with no success there is nothing for BIPOP's small regime to refine: every restart is a large one)
    flat = OptimizeSettings(seed=1, min_evals=200, max_evals=10_000, stall_generations=5, max_restarts=3)
    state = new_state(flat)
    while stop_reason(state, flat) is None:
        step(state, lambda xs: [EvalRecord(1.0, True, 0.0) for _ in xs])
        restart_if_stalled(state, flat)
    assert state.restarts == 3 and popsize_of(state) == 80 and state.large_restarts == 3
    assert stop_reason(state, flat).startswith("converged")
    # a success above the threshold: a stall restarts (the regimes alternate) while budget remains, and the
    # run ends on its budget, never "converged" with evaluations left
    done = OptimizeSettings(seed=1, min_evals=50, max_evals=2_000, stall_generations=5, stop_threshold=0.5,
                            max_restarts=1_000)
    state = new_state(done)
    regimes = []
    while (reason := stop_reason(state, done)) is None:
        step(state, lambda xs: [EvalRecord(1.0, False, 0.0, success=True) for _ in xs])
        if restart_if_stalled(state, done):
            regimes.append(state.regime)
    assert reason == "budget" and state.evaluations + popsize_of(state) > done.max_evals
    assert regimes[0] == "small" and "large" in regimes  # the first success is refined first (BIPOP)
    assert sum(state.regime_evals) == state.evaluations


def _closing_in(state, settings, success):
    """12 generations of a population closing in on an early lucky candidate: its median falls, its best
    (0.5, the first candidate) does not. Returns whether any generation restarted the search."""
    restarted = False
    for g in range(12):
        step(state, lambda xs, g=g: [EvalRecord(0.5 if i == 0 and g == 0 else 10.0 - g + 0.01 * i, False, 0.0,
                                                success) for i, _ in enumerate(xs)])
        restarted |= restart_if_stalled(state, settings)
    return restarted


@pytest.mark.parametrize("rule", ["hybrid", "median"])
def test_a_best_that_sits_still_while_the_median_improves_is_not_a_stall_before_a_success(rule):
    s = OptimizeSettings(seed=1, stall_generations=5, max_evals=10_000, stall_rule=rule)
    assert not _closing_in(new_state(s), s, success=False)
    still = new_state(s)  # best and median both still: a stall under every rule
    for _ in range(12):
        step(still, lambda xs: [EvalRecord(10.0 + 0.01 * i if i else 0.5, False, 0.0, True)
                                for i, _ in enumerate(xs)])
    assert restart_if_stalled(still, s) and still.regime == "small"


def test_once_a_success_exists_a_best_that_sits_still_is_a_stall():
    """The hybrid rule (default): a success that the search no longer improves is refined by a small restart,
    even while the rest of the population still closes in on it (warm starts: a success from the first
    candidate on); the median rule of v0.4 waited for the median too."""
    hybrid = OptimizeSettings(seed=1, stall_generations=5, max_evals=10_000)
    assert hybrid.stall_rule == "hybrid"
    state = new_state(hybrid)
    assert _closing_in(state, hybrid, success=True) and state.regime == "small"
    median = OptimizeSettings(seed=1, stall_generations=5, max_evals=10_000, stall_rule="median")
    assert not _closing_in(new_state(median), median, success=True)


def test_a_small_restart_searches_around_the_best_success():
    s = OptimizeSettings(seed=7, stall_generations=3, max_evals=10_000)
    state = new_state(s)
    target = np.linspace(-1, 1, 8)
    while not restart_if_stalled(state, s):
        step(state, lambda xs: [EvalRecord(float(np.sum((x - target) ** 2) > 100) + 1.0, False, 0.0, True)
                                for x in xs])
    assert state.regime == "small" and state.restarts == 1
    assert s.popsize // 2 <= popsize_of(state) <= s.popsize and s.sigma0 / 10 <= state.es.sigma <= s.sigma0
    best = state.best_x.copy()
    xs, _ = step(state, sphere)
    assert np.array_equal(xs[0], best) and not np.array_equal(xs[1], best)  # the best is injected first
    resumed = CmaState.loads(state.dumps(), s)  # a small regime's population passes the checkpoint checks
    assert resumed.regime == "small" and resumed.regime_evals == state.regime_evals


def test_budget_is_never_exceeded_by_a_grown_population():
    s = OptimizeSettings(seed=3, max_evals=200, stall_generations=2, min_evals=0)
    state = new_state(s)
    while stop_reason(state, s) is None:
        step(state, lambda xs: [EvalRecord(1.0, True, 0.0) for _ in xs])
        restart_if_stalled(state, s)
    assert state.restarts >= 1 and state.evaluations <= 200


def test_resume_across_restarts_is_bit_identical():
    s = OptimizeSettings(seed=4, max_evals=2000, stall_generations=3, min_evals=0, stop_threshold=10.0)

    def drive(state, n_gen, snapshot_at=None):
        snap = None
        for g in range(n_gen):
            if stop_reason(state, s) is not None:
                break
            step(state, rugged)
            restart_if_stalled(state, s)
            if g == snapshot_at:
                snap = state.dumps()
        return state, snap

    straight, snap = drive(new_state(s), 60, snapshot_at=20)
    assert straight.restarts >= 2  # the snapshot and the end straddle restarts
    resumed = CmaState.loads(snap)
    assert resumed.restarts < straight.restarts
    resumed, _ = drive(resumed, 60 - 21)
    assert resumed.restarts == straight.restarts and resumed.evaluations == straight.evaluations
    assert resumed.best_history == straight.best_history and np.array_equal(resumed.es.mean, straight.es.mean)


def test_warm_start_is_the_first_candidate():
    x0 = tuple(np.linspace(-0.3, 0.4, 8))
    state = new_state(OptimizeSettings(seed=1, x0=x0))
    xs, _ = step(state, sphere)
    assert np.array_equal(xs[0], np.array(x0)) and not np.array_equal(xs[1], np.array(x0))


def test_threshold_stop_needs_a_success():
    """A low objective that is not a success (balance kept but the motion not done) never stops the run."""
    s = OptimizeSettings(seed=1, stop_threshold=100.0, max_evals=40, min_evals=10_000, popsize=5)
    state = new_state(s)

    def lazy(xs):  # every candidate scores under the threshold, only candidates with x0 > 0.5 succeed
        return [EvalRecord(1.0, False, 0.0, success=bool(x[0] > 0.5)) for x in xs]

    reasons = []
    while (reason := stop_reason(state, s)) is None:
        _, records = step(state, lazy)
        reasons.append(any(r.success for r in records))
    if reason == "threshold":
        assert reasons[-1] and state.best_success_objective < 100.0
    else:
        assert reason == "budget" and not any(reasons)
    never = OptimizeSettings(seed=1, stop_threshold=100.0, max_evals=30, popsize=5)
    state = new_state(never)
    while (reason := stop_reason(state, never)) is None:
        step(state, lambda xs: [EvalRecord(1.0, False, 0.0, success=False) for _ in xs])
    assert reason != "threshold"  # budget, or a flat stall with no budget left to restart


def test_an_unknown_stall_rule_is_refused():
    from cmrt.errors import CmrtError

    with pytest.raises(CmrtError, match="stall_rule must be one of hybrid, median, best"):
        OptimizeSettings(stall_rule="patience")
