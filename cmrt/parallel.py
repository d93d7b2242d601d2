"""Evaluation backends for a generation: serial, loky (joblib processes), dask.

The same candidate gets the same objective on every backend: the simulation is
deterministic and each worker process builds the same model and settled state (both
cached per process, so a worker compiles the MJCF once, not per evaluation). BLAS is
limited to one thread per process (set before numpy loads, in ``cmrt/__init__``):
the matrices are tiny and thread pools only add overhead and oversubscription.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import joblib
import numpy as np

from cmrt.curve import Cmrt
from cmrt.errors import CmrtError
from cmrt.objective import evaluate
from cmrt.optimize import EvalRecord
from cmrt.simulate import simulate
from cmrt.task import Task

BACKENDS = ("serial", "loky", "dask")


def evaluate_candidate(task: Task, x: np.ndarray) -> EvalRecord:
    """Simulate and score one parameter vector (module-level: picklable for workers)."""
    t0 = time.perf_counter()
    ev = evaluate(task, simulate(task, Cmrt.from_params(x, task.clip_s)))
    return EvalRecord(objective=float(ev.objective), fell=bool(ev.fell), seconds=time.perf_counter() - t0)


class Evaluator:
    """Scores generations on one backend; create it once (it connects to dask up front,
    so an unreachable scheduler fails before anything is written) and ``close()`` it."""

    def __init__(self, backend: str = "serial", workers: int = 2, scheduler: str | None = None):
        if backend not in BACKENDS:
            raise CmrtError(f"unknown backend '{backend}' (choose from {', '.join(BACKENDS)})")
        if workers < 1:
            raise CmrtError("--workers must be >= 1")
        if scheduler and backend != "dask":
            raise CmrtError("--scheduler needs --backend dask")
        self.backend, self.workers = backend, workers
        self._client = self._cluster = None
        if backend == "dask":
            self._client, self._cluster = _dask_client(scheduler, workers)

    def __call__(self, task: Task, xs: Sequence[np.ndarray]) -> list[EvalRecord]:
        if self.backend == "serial":
            return [evaluate_candidate(task, x) for x in xs]
        jobs = (joblib.delayed(evaluate_candidate)(task, x) for x in xs)
        if self.backend == "loky":
            return joblib.Parallel(n_jobs=self.workers, backend="loky")(jobs)
        with joblib.parallel_config(backend="dask"):
            return joblib.Parallel(n_jobs=-1)(jobs)

    def close(self) -> None:
        if self._client is not None:
            self._client.close()
        if self._cluster is not None:
            self._cluster.close()

    def __enter__(self) -> Evaluator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _dask_client(scheduler: str | None, workers: int):
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:  # pragma: no cover - dask is a dependency
        raise CmrtError("the dask backend needs dask[distributed]") from None
    if scheduler:
        try:
            return Client(scheduler, timeout="5s"), None
        except (OSError, TimeoutError, ValueError) as exc:
            raise CmrtError(f"cannot reach dask scheduler {scheduler}: {type(exc).__name__}") from None
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
    return Client(cluster), cluster
