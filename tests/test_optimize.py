import numpy as np

from cmrt.optimize import CmaState, EvalRecord, OptimizeSettings, new_state, step, stop_reason


def sphere(xs):
    return [EvalRecord(float(np.sum((x - 0.3) ** 2)), False, 0.0, success=True) for x in xs]


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
    # a flat objective: no slow-convergence stop before min_evals, then one
    flat = OptimizeSettings(seed=1, min_evals=200, max_evals=10_000, stall_generations=5)
    state = new_state(flat)
    while stop_reason(state, flat) is None:
        step(state, lambda xs: [EvalRecord(1.0, True, 0.0) for _ in xs])
    assert state.evaluations >= 200 and stop_reason(state, flat).startswith("converged")


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
    assert reason == "budget"
