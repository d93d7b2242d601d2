"""--init auto: the nearest known successful CMRT of the task, stored with the run."""

import json

import numpy as np
import pytest

from cmrt.errors import CmrtError
from cmrt.motion.curve import Cmrt
from cmrt.motion.library import load_entries
from cmrt.motion.taskfile import load_task
from cmrt.service.jobs import submit
from cmrt.service.store import open_store
from cmrt.service.warmstart import COLD, nearest_start, resolve_init, task_distance

BEND = load_task("bend")


def test_library_is_the_start_when_the_store_has_nothing(tmp_path):
    with open_store(tmp_path / "s.sqlite") as store:
        start = nearest_start(store, BEND.with_speed(0.4))
        assert start.source == "library (duration_s 0.4)" and start.distance == 0.0
        shipped = [e["cmrt"] for e in load_entries() if e["task"] == "bend" and e["speed"] == 0.4]
        assert any(np.allclose(start.params, Cmrt.from_dict(c).to_params()) for c in shipped)
        # between library speeds: the nearer one
        assert nearest_start(store, BEND.with_speed(0.47)).source == "library (duration_s 0.4)"
        assert nearest_start(store, BEND.with_speed(0.55)).source == "library (duration_s 0.6)"
        # another clip length: nothing to start from
        assert nearest_start(store, BEND.with_speed(0.4).with_params(clip_s=3.0)) is None
        assert resolve_init(store, BEND.with_speed(0.4).with_params(clip_s=3.0), "auto") == COLD


def _done_run(store, task, params, objective):
    rid = submit(store, task, init="none")
    with store.transaction() as conn:
        conn.execute("UPDATE runs SET status = 'done', best_success = 1, best_objective = ?, best_params = ? "
                     "WHERE id = ?", (objective, json.dumps(list(params)), rid))
    return rid


def test_a_successful_stored_run_wins_at_equal_distance(tmp_path):
    task = BEND.with_speed(0.4)
    with open_store(tmp_path / "s.sqlite") as store:
        rid = _done_run(store, task, np.full(8, 0.1), 0.9)  # worse objective than the library, same task
        start = nearest_start(store, task)
        assert start.source == f"run {rid}" and start.params == tuple(np.full(8, 0.1))
        nearer = _done_run(store, task.with_speed(0.45), np.full(8, 0.2), 0.5)
        assert nearest_start(store, task.with_speed(0.44)).source == f"run {nearer}"
        # the start is stored with the run: later store changes do not move it
        queued = submit(store, task)
        assert store.run(queued).init_source == f"run {rid}"
        assert store.run(queued).init_params == (0.1,) * 8


def test_distance_uses_the_declared_ranges():
    task = BEND.with_speed(0.4)
    lo, hi = task.param_ranges["duration_s"]
    assert task_distance(task, task.params) == 0.0
    assert task_distance(task, {**task.params, "duration_s": 0.5}) == pytest.approx(0.1 / (hi - lo))
    assert task_distance(task, {**task.params, "stop_threshold": 5.0}) == 0.0  # not physics


def test_bad_init_is_refused(tmp_path):
    with open_store(tmp_path / "s.sqlite") as store:
        for bad in ("sometimes", 1.5, True):
            with pytest.raises(CmrtError, match="--init"):
                resolve_init(store, BEND, bad)
        with pytest.raises(CmrtError, match="no run 7"):
            resolve_init(store, BEND, 7)
        assert store.runs() == []  # nothing written


def test_warm_started_run_evaluates_its_start_first(tmp_path):
    from cmrt.optimize.parallel import Evaluator
    from cmrt.service.jobs import claim, run_claimed

    task = BEND.with_speed(0.4)
    with open_store(tmp_path / "s.sqlite") as store, Evaluator("batch") as ev:
        rid = submit(store, task, seed=1, max_evals=10, popsize=5)
        run_claimed(store, claim(store, "t", run_id=rid), ev)
        first = store.evaluations(rid)[0]
        assert np.allclose(first.params, nearest_start(None, task).params)
        assert first.success is True  # the library CMRT succeeds at its own speed
        assert store.run(rid).stop_reason == "threshold" and store.run(rid).evaluations == 5
    assert Cmrt.from_params(np.array(first.params), task.clip_s).clip_s == task.clip_s


def test_a_robust_run_starts_from_a_robust_cmrt_and_a_plain_one_from_a_plain(tmp_path):
    task = BEND.with_speed(0.4)
    with open_store(tmp_path / "s.sqlite") as store:
        rid = _done_run(store, task.with_robust(), np.full(8, 0.3), 0.7)
        assert nearest_start(store, task.with_robust()).source == f"run {rid}"
        assert nearest_start(store, task).source == "library (duration_s 0.4)"
        assert nearest_start(None, task.with_robust()).source == "library robust (duration_s 0.4)"
