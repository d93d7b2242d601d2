"""Evaluation backends for a generation.

* ``serial``: one candidate after another in this process;
* ``batch`` (default): the whole generation stepped in lockstep on a
  ``mujoco.batch.Batch`` with the vectorised controller, on all cores' threads;
* ``loky`` / ``dask``: candidates spread over joblib worker processes, or over a
  ``dask.distributed`` cluster through joblib's dask backend;
* ``loky+batch`` / ``dask+batch``: the generation split into one batch per worker.

The same candidate gets the same objective on every backend: MuJoCo is
deterministic, its batch is bit-identical to stepping each simulation alone, the
controller's arithmetic is row-wise, and each worker process builds the same model
and settled state (both cached per process, so a worker compiles the MJCF once, not
per evaluation). BLAS is limited to one thread per process (``cmrt/__init__``).
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import replace

import joblib
import numpy as np

from cmrt.body.props import prop_class
from cmrt.errors import CmrtError, TransientFault
from cmrt.modes import BACKENDS
from cmrt.motion.curve import Cmrt
from cmrt.motion.ensemble import combine, training_members
from cmrt.motion.task import Task
from cmrt.optimize.memory import bound_heap_growth, clips_per_batch
from cmrt.sim.clip3d import clip_3d
from cmrt.sim.objective import EvalRecord, evaluate
from cmrt.sim.simulate import simulate_batch


def evaluate_candidate(task: Task, x: np.ndarray) -> EvalRecord:
    """Simulate and score one parameter vector (module-level: picklable for workers)."""
    return evaluate_batch(task, [x], threads=1)[0]


def evaluate_batch(task: Task, xs: Sequence[np.ndarray], threads: int | None = None) -> list[EvalRecord]:
    """Simulate and score candidates in lockstep; seconds are the batch's wall time shared equally.

    A robust task (``task.robust.enabled``) runs every candidate's ensemble members in the same batch and
    scores each candidate by ``ensemble.combine``: a success only if every member is one. The candidates
    are simulated in batches of at most ``memory.clips_per_batch`` clips (a candidate's members stay
    together), each scored and dropped before the next: memory is bounded whatever the population."""
    t0 = time.perf_counter()
    bound_heap_growth()
    members = training_members(task, task.robust, prop_class(task.prop).mass_body is not None) \
        if task.robust.enabled else [None]
    per_batch = max(1, clips_per_batch(task) // len(members))
    out: list[EvalRecord] = []
    for a in range(0, len(xs), per_batch):
        out += _score_batch(task, xs[a : a + per_batch], members, threads)
    each = (time.perf_counter() - t0) / max(len(xs), 1)
    return [replace(r, seconds=each) for r in out]


def _score_batch(task: Task, xs: Sequence[np.ndarray], members: list, threads: int | None) -> list[EvalRecord]:
    curves = [Cmrt.from_params(x, task.clip_s) for x in xs]
    if task.body != "planar":  # the 3D body's clips, one after another (cmrt.sim.clip3d): no lockstep batch yet
        scores = [clip_3d(task, curve, member) for curve in curves for member in members]
    elif members == [None]:
        scores = [evaluate(task, tr) for tr in simulate_batch(task, curves, threads=threads)]
    else:
        trajs = simulate_batch(task, [c for c in curves for _ in members], threads=threads,
                               perturbations=members * len(curves))
        scores = [evaluate(members[j % len(members)].task_variant(task), tr) for j, tr in enumerate(trajs)]
    k = len(members)
    return [_candidate(scores[i * k : (i + 1) * k], task.robust if members != [None] else None)
            for i in range(len(curves))]


def _candidate(group: list, robust) -> EvalRecord:
    """One candidate's record from its members' scores (each an Evaluation or a 3D clip): the ensemble's combined
    objective (``robust``: its spec) or the nominal clip's, a success only if every member is one."""
    objective = float(group[0].objective) if robust is None else combine([float(e.objective) for e in group], robust)
    return EvalRecord(objective=objective, fell=any(bool(e.fell) for e in group), seconds=0.0,
                      success=all(bool(e.success) for e in group))


def _chunks(xs: Sequence[np.ndarray], k: int) -> list[list[np.ndarray]]:
    size = -(-len(xs) // k)
    return [list(xs[i : i + size]) for i in range(0, len(xs), size)]


PR_SET_PDEATHSIG = 1  # prctl(2): the signal this process gets when the thread that started it ends
PARENT_POLL_S = 1.0  # where there is no prctl: how often a worker process looks for its parent


def die_with_parent(parent_pid: int) -> None:
    """A loky worker process's initializer: end when the process that started it ends, however it ends. loky's
    workers notice a dead parent only when they next look for work, and a ``kill -9`` of a worker left its
    children running (2 x 240 MB and loky's trackers, still alive 90 s later). On Linux the kernel sends this
    process SIGKILL when its parent ends (``PR_SET_PDEATHSIG``; loky starts workers from the thread that calls
    the executor, which lives as long as the evaluator); elsewhere a thread polls the parent's pid. A parent gone
    before this ran is seen at once. loky's resource trackers end by themselves once no worker holds their pipe."""
    armed = False
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            armed = ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL) == 0
    if not armed:
        threading.Thread(target=_watch_parent, args=(parent_pid,), name="watch-parent", daemon=True).start()
    if os.getppid() != parent_pid:
        os._exit(1)


def _watch_parent(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(PARENT_POLL_S)
    os._exit(1)


#: exception class names that mean a worker process died under an evaluation: dask's KilledWorker (a task
#: killed its worker too often), loky's TerminatedWorkerError / BrokenProcessPool. Matched by name so that
#: this module imports neither dask nor loky internals up front.
LOST_WORKER_ERRORS = frozenset({"KilledWorker", "TerminatedWorkerError", "BrokenProcessPool", "CommClosedError"})


class Evaluator:
    """Scores generations on one backend; create it once (it connects to dask up front,
    so an unreachable scheduler fails before anything is written) and ``close()`` it."""

    def __init__(self, backend: str = "batch", workers: int = 2, scheduler: str | None = None):
        if backend not in BACKENDS:
            raise CmrtError(f"unknown backend '{backend}' (choose from {', '.join(BACKENDS)})")
        if workers < 1:
            raise CmrtError("--workers must be >= 1")
        if scheduler and not backend.startswith("dask"):
            raise CmrtError("--scheduler needs --backend dask")
        self.backend, self.workers = backend, workers
        self._client = self._cluster = None
        if backend.startswith("dask"):
            self._client, self._cluster = _dask_client(scheduler, workers)

    def __call__(self, task: Task, xs: Sequence[np.ndarray]) -> list[EvalRecord]:
        """Score candidates ``xs`` of ``task``, in order. A worker process or dask worker that died under
        the evaluation is a :class:`TransientFault` (the run is retried from its checkpoint)."""
        try:
            return self._evaluate(task, xs)
        except Exception as exc:
            if type(exc).__name__ in LOST_WORKER_ERRORS:
                raise TransientFault(f"{self.backend} worker lost ({type(exc).__name__})") from exc
            raise

    def _evaluate(self, task: Task, xs: Sequence[np.ndarray]) -> list[EvalRecord]:
        if self.backend == "serial":
            return [evaluate_candidate(task, x) for x in xs]
        if self.backend == "batch":
            return evaluate_batch(task, xs)
        if self.backend.endswith("+batch"):  # one single-threaded batch per worker process
            jobs = (joblib.delayed(evaluate_batch)(task, chunk, 1) for chunk in _chunks(xs, self.workers))
        else:
            jobs = (joblib.delayed(evaluate_candidate)(task, x) for x in xs)
        if self.backend.startswith("loky"):
            out = joblib.Parallel(n_jobs=self.workers, backend="loky", initializer=die_with_parent,
                                  initargs=(os.getpid(),))(jobs)
        else:
            with joblib.parallel_config(backend="dask"):
                out = joblib.Parallel(n_jobs=-1)(jobs)
        return [r for part in out for r in part] if self.backend.endswith("+batch") else out

    def close(self) -> None:
        """Shut down the backend's processes or cluster (if this evaluator started them)."""
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
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                           silence_logs=logging.ERROR)
    return Client(cluster), cluster
