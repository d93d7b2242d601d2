"""CMA-ES driver (pycma ask/tell) over the 8 CMRT parameters. Knows nothing of SQLite.

Stopping rules (ABC section 4.1), checked between generations:

* ``threshold``: a *successful* candidate (balance held, motion performed, settled:
  ``cmrt.objective``) scores below the task's ``stop_threshold``;
* ``budget``: the next generation would pass ``max_evals`` evaluations;
* ``converged``: the search stalled - its best objective improved by less than
  ``stall_tol`` (relative) over ``stall_generations`` generations, or pycma's own
  termination criteria fired - after a success was found and ``min_evals`` (700, as in
  the paper) evaluations were done.

A search that stalls *without* a success (or before ``min_evals``) is not stopped but
restarted (IPOP-CMA-ES, Auger & Hansen 2005): a fresh CMA-ES from the same start point
and step size with the population multiplied by ``popsize_factor``: a seed whose first
search stalls among falls gets further searches inside the same budget, each with a
larger population (which averages over the rugged landscape that falls make). A run
whose start came from another CMRT (a warm start) has that CMRT injected as its first
candidate, so a start that already succeeds is seen.

Determinism: pycma seeds numpy's *global* RNG unless told otherwise; we pass
``seed=nan`` and our own ``randn`` drawing from a private ``numpy.random.Generator``
seeded by the run's seed; restarts keep drawing from the same generator. The whole
:class:`CmaState` (pycma object + generator + bookkeeping) is pickled after every
generation, so a resumed run continues - across restarts too - with exactly the
samples an uninterrupted one would draw.
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
from cmrt.objective import EvalRecord

N_PARAMS = 2 * N_KNOTS


@dataclass(frozen=True)
class OptimizeSettings:
    """The optimizer's settings; the defaults here are the only place they are written (CLI, jobs read them)."""

    seed: int = 1
    max_evals: int = 3000
    min_evals: int = 700  # slow-convergence tests only after this many evaluations (ABC 4.1)
    popsize: int = 10
    sigma0: float = 0.5  # in parameter units: 2.5 cm of CoM shift, knot-gap log-ratio 0.5
    stop_threshold: float = 0.0
    stall_generations: int = 20
    stall_tol: float = 1e-3
    x0: tuple[float, ...] | None = None  # warm start (parameters of a stored result)
    max_restarts: int = 9  # IPOP restarts when the search stalls without a success
    popsize_factor: float = 2.0  # each restart multiplies the population by this


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
    restarts: int = 0
    restart_history: list[float] = field(default_factory=list)  # best of the current restart, per generation
    randn: _Randn | None = None  # the private generator every restart draws from

    def __setstate__(self, state: dict) -> None:
        """Checkpoints written before restarts existed resume too."""
        state.setdefault("restarts", 0)
        state.setdefault("restart_history", list(state.get("best_history", [])))
        state.setdefault("randn", state["es"].opts["randn"])
        self.__dict__.update(state)

    def dumps(self) -> bytes:
        """The checkpoint blob stored after every generation."""
        return pickle.dumps(self, protocol=pickle.HIGHEST_PROTOCOL)

    @staticmethod
    def loads(blob: bytes) -> CmaState:
        return pickle.loads(blob)


def _new_es(settings: OptimizeSettings, randn: _Randn, popsize: int) -> cma.CMAEvolutionStrategy:
    x0 = np.zeros(N_PARAMS) if settings.x0 is None else np.asarray(settings.x0, dtype=float)
    opts = {
        "popsize": popsize,
        "seed": np.nan,
        "randn": randn,
        "verbose": -9,
        "verb_log": 0,
        "verb_disp": 0,
        "maxfevals": np.inf,  # our own budget rule decides
    }
    es = cma.CMAEvolutionStrategy(x0, settings.sigma0, opts)
    if settings.x0 is not None:
        es.inject([x0], force=True)  # the warm start itself is the first candidate
    return es


def new_state(settings: OptimizeSettings) -> CmaState:
    """A fresh search (first generation not yet asked)."""
    randn = _Randn(settings.seed)
    return CmaState(es=_new_es(settings, randn, settings.popsize), randn=randn)


def popsize_of(state: CmaState) -> int:
    """The current (re)start's population."""
    return int(state.es.popsize)


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
    gen_best = min(objectives)
    state.restart_history.append(min(gen_best, state.restart_history[-1]) if state.restart_history else gen_best)
    return xs, records


def _stalled(state: CmaState, settings: OptimizeSettings) -> str | None:
    """Why the current (re)start has stopped making progress, or None."""
    h = state.restart_history
    if len(h) > settings.stall_generations:
        old, new = h[-settings.stall_generations - 1], h[-1]
        if old - new <= settings.stall_tol * max(abs(old), 1e-12):
            return "converged"
    cma_stop = {k: v for k, v in state.es.stop().items() if k != "maxfevals"}
    if cma_stop:
        return "converged:" + ",".join(sorted(cma_stop))
    return None


def _restart_popsize(state: CmaState, settings: OptimizeSettings) -> int | None:
    """The population of the next restart, or None when the stalled search should stop instead: it has
    its success and the paper's minimum effort, or restarts (or budget for two generations) ran out."""
    if state.best_success_objective < np.inf and state.evaluations >= settings.min_evals:
        return None
    popsize = int(round(settings.popsize * settings.popsize_factor ** (state.restarts + 1)))
    if state.restarts >= settings.max_restarts or state.evaluations + 2 * popsize > settings.max_evals:
        return None
    return popsize


def stop_reason(state: CmaState, settings: OptimizeSettings) -> str | None:
    """Why the run should stop now (threshold, budget, converged...), or None to go on."""
    if state.best_success_objective < settings.stop_threshold:
        return "threshold"
    if state.evaluations >= settings.max_evals or (
            state.evaluations and state.evaluations + popsize_of(state) > settings.max_evals):
        return "budget"  # never past max_evals, but at least one generation
    why = _stalled(state, settings)
    if why and _restart_popsize(state, settings) is None:
        return why
    return None


def restart_if_stalled(state: CmaState, settings: OptimizeSettings) -> bool:
    """After a generation: restart a stalled search with a larger population (IPOP) unless it should stop.
    Called before the checkpoint is written, so a resumed run sees the restart as it happened."""
    if state.best_success_objective < settings.stop_threshold or not _stalled(state, settings):
        return False
    popsize = _restart_popsize(state, settings)
    if popsize is None:
        return False
    state.es = _new_es(settings, state.randn, popsize)
    state.restarts += 1
    state.restart_history = []
    return True


def best_cmrt(state: CmaState, clip_s: float) -> Cmrt:
    """The best candidate so far as a CMRT."""
    return Cmrt.from_params(state.best_x, clip_s)
