"""Same seed, same result on every backend (loky processes and a real dask LocalCluster)."""

import numpy as np
import pytest

from cmrt.errors import CmrtError
from cmrt.motion.taskfile import load_task
from cmrt.optimize.parallel import Evaluator
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
    """The 3D leg lift's clips (cmrt.sim.clip3d, one after another in each process) score the same everywhere."""
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
