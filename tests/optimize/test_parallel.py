"""Same seed, same result on every backend (loky processes and a real dask LocalCluster)."""

import numpy as np
import pytest

from cmrt.errors import CmrtError
from cmrt.motion.curve import Cmrt
from cmrt.motion.ensemble import training_members
from cmrt.motion.taskfile import load_task
from cmrt.optimize.parallel import Evaluator, clips_3d, threads_3d
from cmrt.service.jobs import claim, run_claimed, submit
from cmrt.service.store import open_store


def optimize_with(tmp_path, backend, task=None, max_evals=16, popsize=8):
    task = task or load_task("bend").with_speed(0.4)
    with open_store(tmp_path / f"{task.name}-{backend}.sqlite") as store:
        rid = submit(store, task, seed=11, max_evals=max_evals, popsize=popsize, backend=backend, init="none")
        with Evaluator(backend, workers=2) as ev:  # dask: a real LocalCluster of 2 worker processes
            run_claimed(store, claim(store, "t", run_id=rid), ev)
        return store.run(rid), store.evaluations(rid)


@pytest.mark.slow  # six optimizations, loky and dask process pools
def test_every_backend_gives_identical_results(tmp_path):
    serial = optimize_with(tmp_path, "serial")
    for backend in ("batch", "loky", "loky+batch", "dask", "dask+batch"):
        run, evals = optimize_with(tmp_path, backend)
        assert run.best_params == serial[0].best_params, backend
        assert run.best_objective == serial[0].best_objective, backend
        assert [e.objective for e in evals] == [e.objective for e in serial[1]], backend


@pytest.mark.slow  # four short optimizations, loky and dask process pools
def test_every_backend_gives_identical_results_on_a_3d_task(tmp_path):
    """The 3D leg lift's clips (cmrt.sim.clip3d, spread over threads in each process) score the same everywhere."""
    lift = load_task("leg-lift").with_params(duration_s=1.5, clip_s=2.5, stop_threshold=0.0)
    serial = optimize_with(tmp_path, "serial", lift, max_evals=8, popsize=4)
    for backend in ("batch", "loky", "dask"):
        run, evals = optimize_with(tmp_path, backend, lift, max_evals=8, popsize=4)
        assert run.best_params == serial[0].best_params, backend
        assert [e.objective for e in evals] == [e.objective for e in serial[1]], backend


@pytest.mark.slow  # waits out the 5 s connect timeout
def test_unreachable_scheduler_is_bad_input():
    with pytest.raises(CmrtError, match="cannot reach dask scheduler"):
        Evaluator("dask", scheduler="tcp://127.0.0.1:1")


@pytest.mark.parametrize("name", ["leg-lift", "bend3d"])
def test_a_3d_generation_on_threads_is_the_clips_one_after_another(name):
    """``clips_3d`` spreads a 3D generation without a prop over threads (a clip's data is its thread's): every
    clip's result is the one it has alone, bit for bit, and in order - a robust candidate's members too. A prop's
    clips (a Python loop, the GIL) keep one thread."""
    assert threads_3d(load_task(name), 5, 2) == 2 and threads_3d(load_task("catch3d"), 5, 2) == 1
    task = load_task(name)
    curves = [Cmrt.from_params(x, task.clip_s) for x in np.random.default_rng(5).normal(scale=0.3, size=(3, 8))]
    jobs = [(c, None) for c in curves] + [(curves[0], m) for m in training_members(task, task.robust, True)[:2]]
    alone, threaded = clips_3d(task, jobs, threads=1), clips_3d(task, jobs, threads=2)
    for a, b in zip(alone, threaded, strict=True):
        assert a.objective == b.objective and a.failed_rules == b.failed_rules
        assert np.array_equal(a.result.qpos, b.result.qpos) and np.array_equal(a.result.cop_xy_m, b.result.cop_xy_m,
                                                                               equal_nan=True)


def test_serial_and_batch_backends_agree_and_bad_options_are_refused():
    """The fast loop's share of the backend test, in this process: the batched backend scores candidates exactly
    as the serial one does, and bad options fail before anything starts."""
    task = load_task("bend").with_speed(0.4)
    xs = list(np.random.default_rng(11).normal(scale=0.5, size=(3, 8)))
    with Evaluator("serial") as serial, Evaluator("batch") as batch:
        assert [r.objective for r in serial(task, xs)] == [r.objective for r in batch(task, xs)]
    for kwargs, words in (({"backend": "gpu"}, "unknown backend"), ({"workers": 0}, "workers"),
                          ({"backend": "batch", "scheduler": "tcp://127.0.0.1:1"}, "needs --backend dask")):
        with pytest.raises(CmrtError, match=words):
            Evaluator(**kwargs)
