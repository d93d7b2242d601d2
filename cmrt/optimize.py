"""CMA-ES driver (pycma ask/tell) over the 8 CMRT parameters. Knows nothing of SQLite.

Stopping rules (ABC section 4.1):

* ``threshold``: a *successful* candidate (balance held, motion performed, settled:
  ``cmrt.objective``) scores below the task's ``stop_threshold``;
* ``budget``: ``max_evals`` evaluations done;
* ``converged``: only after ``min_evals`` evaluations (700, as in the paper), the best
  objective improved by less than ``stall_tol`` (relative) over ``stall_generations``
  generations, or pycma's own termination criteria fire.

Determinism: pycma seeds numpy's *global* RNG unless told otherwise; we pass
``seed=nan`` and our own ``randn`` drawing from a private ``numpy.random.Generator``
seeded by the run's seed. The whole :class:`CmaState` (pycma object + generator +
bookkeeping) is pickled after every generation, so a resumed run continues with
exactly the samples an uninterrupted one would draw.
"""

from __future__ import annotations

import pickle
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # pycma warns when matplotlib is missing
    import cma

from cmrt.curve import N_KNOTS, Cmrt

N_PARAMS = 2 * N_KNOTS


@dataclass(frozen=True)
class OptimizeSettings:
    seed: int = 1
    max_evals: int = 3000
    min_evals: int = 700  # slow-convergence tests only after this many evaluations (ABC 4.1)
    popsize: int = 10
    sigma0: float = 0.5  # in parameter units: 2.5 cm of CoM shift, knot-gap log-ratio 0.5
    stop_threshold: float = 0.0
    stall_generations: int = 20
    stall_tol: float = 1e-3
    x0: tuple[float, ...] | None = None  # warm start (parameters of a stored result)


@dataclass(frozen=True)
class EvalRecord:
    """One candidate's score, as stored."""

    objective: float
    fell: bool
    seconds: float
    success: bool = False


class _Randn:
    """pycma's ``randn`` option backed by a private generator (picklable, unlike a lambda)."""

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)

    def __call__(self, *shape: int) -> np.ndarray:
        return self.rng.standard_normal(shape)


@dataclass
class CmaState:
    """Everything needed to continue a run bit-identically (pickled as the checkpoint)."""

    es: cma.CMAEvolutionStrategy
    generation: int = 0
    evaluations: int = 0
    best_x: np.ndarray | None = None
    best_objective: float = float("inf")
    best_fell: bool = True
    best_success: bool = False
    best_history: list[float] = field(default_factory=list)
    # the best successful candidate (the threshold stop looks at it; it is usually the best overall)
    best_success_objective: float = float("inf")

    def dumps(self) -> bytes:
        return pickle.dumps(self, protocol=pickle.HIGHEST_PROTOCOL)

    @staticmethod
    def loads(blob: bytes) -> CmaState:
        return pickle.loads(blob)


def new_state(settings: OptimizeSettings) -> CmaState:
    x0 = np.zeros(N_PARAMS) if settings.x0 is None else np.asarray(settings.x0, dtype=float)
    opts = {
        "popsize": settings.popsize,
        "seed": np.nan,
        "randn": _Randn(settings.seed),
        "verbose": -9,
        "verb_log": 0,
        "verb_disp": 0,
        "maxfevals": np.inf,  # our own budget rule decides
    }
    return CmaState(es=cma.CMAEvolutionStrategy(x0, settings.sigma0, opts))


def step(state: CmaState, evaluate: Callable[[Sequence[np.ndarray]], list[EvalRecord]]) -> tuple[list, list]:
    """One generation: ask, evaluate, tell. Mutates ``state``; returns (xs, records)."""
    xs = [np.asarray(x, dtype=float) for x in state.es.ask()]
    records = evaluate(xs)
    objectives = [r.objective for r in records]
    state.es.tell(xs, objectives)
    state.generation += 1
    state.evaluations += len(xs)
    i = int(np.argmin(objectives))
    if objectives[i] < state.best_objective:
        state.best_x, state.best_objective = xs[i].copy(), objectives[i]
        state.best_fell, state.best_success = records[i].fell, records[i].success
    wins = [r.objective for r in records if r.success]
    if wins:
        state.best_success_objective = min(state.best_success_objective, min(wins))
    state.best_history.append(state.best_objective)
    return xs, records


def stop_reason(state: CmaState, settings: OptimizeSettings) -> str | None:
    if state.best_success_objective < settings.stop_threshold:
        return "threshold"
    if state.evaluations >= settings.max_evals:
        return "budget"
    if state.evaluations < settings.min_evals:
        return None
    h = state.best_history
    if len(h) > settings.stall_generations:
        old, new = h[-settings.stall_generations - 1], h[-1]
        if old - new <= settings.stall_tol * max(abs(old), 1e-12):
            return "converged"
    cma_stop = {k: v for k, v in state.es.stop().items() if k != "maxfevals"}
    if cma_stop:
        return "converged:" + ",".join(sorted(cma_stop))
    return None


def best_cmrt(state: CmaState, clip_s: float) -> Cmrt:
    return Cmrt.from_params(state.best_x, clip_s)
