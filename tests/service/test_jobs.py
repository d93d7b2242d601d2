"""Queue semantics with real worker processes: crash/resume and concurrency."""

import os
import signal
import sqlite3
import time

import pytest

from cmrt.errors import CmrtError
from cmrt.motion.taskfile import load_task
from cmrt.optimize.parallel import Evaluator
from cmrt.service.jobs import claim, optimize_family, run_claimed, submit, work
from cmrt.service.store import open_store
from tests.service_helpers import spawn_worker

TASK = load_task("bend").with_speed(0.4)


def finished_run(path, **kw):
    with open_store(path) as store:
        rid = submit(store, TASK, init="none", **kw)
        c = claim(store, "test", run_id=rid)
        run_claimed(store, c, Evaluator("serial"))
        return store.run(rid), store.evaluations(rid)


def kill_worker_after(path, rid: int, generations: int, backend: str) -> None:
    """Start a worker on the store and SIGKILL it once the run has committed ``generations``."""
    worker = spawn_worker(path, "--once", backend=backend)
    deadline = time.time() + 300
    while time.time() < deadline:
        with sqlite3.connect(path) as con:
            gens = con.execute("SELECT COUNT(*) FROM generations WHERE run_id = ?", (rid,)).fetchone()[0]
        if gens >= generations:
            break
        time.sleep(0.02)
    os.kill(worker.pid, signal.SIGKILL)
    worker.wait()


@pytest.mark.slow  # a whole (small) optimization, serial
def test_run_stores_every_evaluation_and_generation(tmp_path):
    run, evals = finished_run(tmp_path / "s.sqlite", seed=3, max_evals=15, popsize=5)
    assert run.status == "done" and run.stop_reason == "budget"
    assert run.evaluations == len(evals) == 15 and run.generations == 3
    assert run.best_objective == min(e.objective for e in evals)
    assert run.baseline_success is False and run.baseline_objective > 5
    assert all(e.success in (True, False) for e in evals)


@pytest.mark.slow  # worker processes, SIGKILL and resume
def test_sigkill_mid_run_then_resume_is_bit_identical(tmp_path):
    kw = dict(seed=7, max_evals=48, popsize=6)
    reference, ref_evals = finished_run(tmp_path / "ref.sqlite", **kw)

    path = tmp_path / "crash.sqlite"
    with open_store(path) as store:
        rid = submit(store, TASK, init="none", **kw)
    kill_worker_after(path, rid, 3, backend="serial")  # slow generations: a kill lands mid-run
    with open_store(path) as store:
        killed = store.run(rid)
    assert killed.status == "running" and 3 <= killed.generations < 8  # really killed mid-run

    resumer = spawn_worker(path, "--until-idle", "--stale-after", "0.01")
    out, err = resumer.communicate(timeout=600)
    assert resumer.returncode == 0, err
    with open_store(path) as store:
        run, evals = store.run(rid), store.evaluations(rid)
    assert run.status == "done" and run.attempt == 2
    assert run.best_params == reference.best_params
    assert run.best_objective == reference.best_objective
    assert run.evaluations == 48 and len(evals) == 48
    assert len({(e.gen, e.idx) for e in evals}) == 48
    assert [(e.params, e.objective) for e in evals] == [(e.params, e.objective) for e in ref_evals]


@pytest.mark.slow  # four worker processes, eight runs
def test_four_workers_eight_jobs_each_done_exactly_once(tmp_path):
    path = tmp_path / "busy.sqlite"
    with open_store(path) as store:
        ids = [submit(store, TASK, seed=s, max_evals=8, popsize=4, init="none") for s in range(8)]
    workers = [spawn_worker(path, "--until-idle", "--json") for _ in range(4)]
    outputs = [w.communicate(timeout=900) for w in workers]
    for w, (_out, err) in zip(workers, outputs, strict=True):
        assert w.returncode == 0, err
        assert "locked" not in err.lower()
    import json

    finished = [rid for out, _ in outputs for rid in json.loads(out.strip().splitlines()[-1])["finished"]]
    assert sorted(finished) == ids  # every job exactly once across the workers
    with open_store(path) as store:
        assert all(r.status == "done" and r.attempt == 1 for r in store.runs())
        assert store.conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        n = store.conn.execute("SELECT COUNT(*), COUNT(DISTINCT run_id || '-' || gen || '-' || idx) FROM evaluations")
        assert tuple(n.fetchone()) == (64, 64)


def test_lost_claim_stops_the_old_worker(tmp_path):
    from cmrt.service.jobs import LostClaim

    with open_store(tmp_path / "s.sqlite") as store:
        rid = submit(store, TASK, seed=1, max_evals=10, popsize=5, init="none")
        first = claim(store, "a", run_id=rid)
        second = claim(store, "b", stale_after_s=0.0, run_id=rid)  # a looked dead
        assert second.attempt == first.attempt + 1
        try:
            run_claimed(store, first, Evaluator("serial"))
            raise AssertionError("the superseded worker wrote into the run")
        except LostClaim:
            pass
        assert store.evaluations(rid) == []


@pytest.mark.slow  # worker processes, robust ensemble runs
def test_sigkilled_robust_run_resumes_bit_identically_across_a_restart(tmp_path):
    """A robust run (7 ensemble members per candidate) whose search restarts (IPOP) after the kill."""
    task = TASK.with_robust()
    kw = dict(seed=7, max_evals=40, popsize=4, init="none", stall_generations=2)
    with open_store(tmp_path / "ref.sqlite") as store:
        rid = submit(store, task, **kw)
        reference = run_claimed(store, claim(store, "ref", run_id=rid), Evaluator("batch"))
        ref_evals = store.evaluations(rid)
    assert reference.restarts >= 1 and reference.robust["enabled"] is True

    path = tmp_path / "crash.sqlite"
    with open_store(path) as store:
        rid = submit(store, task, **kw)
    kill_worker_after(path, rid, 2, backend="batch")
    with open_store(path) as store:
        killed = store.run(rid)
    assert killed.status == "running" and killed.restarts < reference.restarts

    resumer = spawn_worker(path, "--until-idle", "--stale-after", "0.01")
    _, err = resumer.communicate(timeout=600)
    assert resumer.returncode == 0, err
    with open_store(path) as store:
        run, evals = store.run(rid), store.evaluations(rid)
    assert run.attempt == 2 and run.restarts == reference.restarts
    assert run.best_params == reference.best_params and run.robustness == reference.robustness
    assert [(e.params, e.objective) for e in evals] == [(e.params, e.objective) for e in ref_evals]


@pytest.mark.slow
def test_a_speed_family_warm_starts_each_member_from_the_previous(tmp_path):
    """``optimize_family`` (``cmrt optimize --speeds``): the first member starts as asked, each later one from
    its neighbour's best with the family step size; a bad step size is refused before anything is queued."""
    tasks = [TASK, TASK.with_speed(0.45)]
    with open_store(tmp_path / "s.sqlite") as store:
        with pytest.raises(CmrtError, match="family_sigma0"):
            optimize_family(store, tasks, family_sigma0=-1.0, init="none")
        assert store.runs() == []
        first, second = optimize_family(store, tasks, Evaluator("batch"), family_sigma0=0.2, init="none",
                                        max_evals=10, popsize=5)
        assert first.init_source == "none" and first.sigma0 == 0.5 and first.speed == 0.4
        assert second.init_source == f"run {first.id}" and second.init_params == first.best_params
        assert second.sigma0 == 0.2 and second.speed == 0.45 and second.status == "done"


def test_work_needs_no_evaluator(tmp_path):
    """``work`` takes the same default (batched) evaluator as ``optimize_now``."""
    with open_store(tmp_path / "s.sqlite") as store:
        rid = submit(store, TASK, init="none", max_evals=5, popsize=5)
        assert work(store, until_idle=True) == [rid]
        assert store.run(rid).status == "done" and store.run(rid).evaluations == 5


def test_a_run_is_never_worse_than_no_cmrt(tmp_path):
    """The slow bend succeeds with no CMRT (0.58, under the task's 0.7 threshold): the zero CMRT is a candidate
    the search knows, so the run's best is at most the baseline, and a threshold stop needs a better success."""
    from cmrt.optimize.driver import ZERO_X, CmaState, know_zero, new_state
    from cmrt.optimize.settings import OptimizeSettings
    from cmrt.service.jobs import optimize_now
    from cmrt.sim.objective import EvalRecord

    slow = load_task("bend").with_speed(1.2)
    with open_store(tmp_path / "s.sqlite") as store:
        run = optimize_now(store, slow, seed=1, max_evals=20, init="none")
    assert run.baseline_success and run.best_objective <= run.baseline_objective
    assert run.stop_reason != "threshold" or run.best_objective < run.baseline_objective
    state = new_state(OptimizeSettings(stop_threshold=0.7))
    know_zero(state, EvalRecord(objective=0.58, fell=False, seconds=0.0, success=True))
    assert (state.best_objective, state.best_success, tuple(state.best_x)) == (0.58, True, tuple(ZERO_X))
    from cmrt.optimize.driver import stop_reason
    assert stop_reason(state, OptimizeSettings(stop_threshold=0.7)) is None  # the zero CMRT alone never stops it
    state.best_success_objective = 0.5  # a search candidate that beats it
    assert stop_reason(state, OptimizeSettings(stop_threshold=0.7)) == "threshold"
    again = CmaState.loads(state.dumps(), OptimizeSettings(stop_threshold=0.7))
    assert again.zero_success_objective == 0.58  # checkpointed


def test_the_slow_convergence_floor_follows_a_smaller_budget_and_a_contradiction_is_refused(tmp_path):
    """``submit(max_evals=60)`` stores min_evals 60 (it stored the default 700 without a word); a min_evals given
    above the budget is refused in one line before anything is written."""
    task = load_task("bend").with_speed(0.4)
    with open_store(tmp_path / "s.sqlite") as store:
        run = store.run(submit(store, task, max_evals=60))
        assert run.min_evals == 60
        assert store.run(submit(store, task)).min_evals == 700
        with pytest.raises(CmrtError, match="min-evals 100 is more than the budget, max-evals 60"):
            submit(store, task, max_evals=60, min_evals=100)
        assert len(store.runs()) == 2


def test_the_search_summary_names_the_start_and_the_stop(tmp_path):
    """What a worker, ``optimize``, ``best``, ``show`` and the dashboard say about a run's search
    (``query.search_summary``), for each start and stop reason."""
    import dataclasses

    from cmrt.service.query import search_summary

    with open_store(tmp_path / "s.sqlite") as store:
        queued = store.run(submit(store, load_task("bend").with_speed(0.6), init="none"))
    run = dataclasses.replace(queued, status="done", evaluations=10, generations=1, stop_reason="threshold",
                              stop_threshold=0.7, init_source="library (duration_s 0.6)", max_evals=3000,
                              sigma0=0.15)
    assert search_summary(run) == (
        "started from the library CMRT (duration_s 0.6), sigma 0.15; it already met the stop threshold 0.7: 10 "
        "evaluations (a search of its own: --init none; below the threshold: --set stop_threshold=0)")
    later = dataclasses.replace(run, generations=30, evaluations=300, init_source="run 12")
    assert search_summary(later) == ("started from run 12's best CMRT, sigma 0.15; stopped at the stop threshold 0.7 "
                                     "after 300 evaluations")
    cold = dataclasses.replace(run, init_source="none", stop_reason="budget", evaluations=3000, sigma0=0.5)
    assert search_summary(cold) == ("started cold from the zero CMRT (sigma 0.5); its budget ran out: 3000 of 3000 "
                                    "evaluations")
    stalled = dataclasses.replace(cold, stop_reason="converged", evaluations=900, restarts=2, stall_generations=20)
    assert search_summary(stalled).endswith("it stopped improving over 20 generations with no restart left that "
                                            "fits: 900 evaluations, 2 restarts")
    assert search_summary(queued) == "started cold from the zero CMRT (sigma 0.5); queued, 0 evaluations so far"


def test_a_warm_start_keeps_a_small_step_size_unless_one_is_given(tmp_path):
    """``sigma0`` None: 0.5 from the zero CMRT, ``FAMILY_SIGMA0`` (0.15) from a known CMRT (the library's for the
    bend at 0.5 s); a step size given is kept either way."""
    from cmrt.optimize.settings import FAMILY_SIGMA0

    task = load_task("bend").with_speed(0.5)
    with open_store(tmp_path / "s.sqlite") as store:
        cold, warm = store.run(submit(store, task, init="none")), store.run(submit(store, task))
        given = store.run(submit(store, task, sigma0=0.3))
    assert cold.sigma0 == 0.5 and cold.init_source == "none"
    assert warm.init_source.startswith("library") and warm.sigma0 == FAMILY_SIGMA0
    assert given.sigma0 == 0.3
