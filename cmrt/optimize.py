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
:class:`CmaState` (pycma object + generator + bookkeeping) is checkpointed after every
generation, so a resumed run continues - across restarts too - with exactly the
samples an uninterrupted one would draw.

Checkpoints are untrusted input (a store is shared and downloaded), so they are not
pickles but :mod:`cmrt.checkpoint` documents, from which nothing is called, and
:meth:`CmaState.loads` then checks what pycma would otherwise trust: pycma ``eval``s
string-valued options (``CMAOptions.eval``: at construction, and on every ``stop()`` for
the options it reads from its signals file), and its options name the functions it calls
(``CMA_eigenmethod``, ``is_feasible``...). A loaded state's options must therefore equal,
key by key and type by type, those :func:`_new_es` builds for the run's population (the
same ``_Randn`` object as ``randn``); with the run's settings the population must also be
the one its restart count implies. So the only strings left among the options are pycma's
two file names, which it never evaluates, and the signals file is switched off
(``signals_filename=""``): pycma would otherwise read ``cma_signals.in`` from the worker's
current directory on every ``stop()`` and evaluate the options it finds there.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields

import numpy as np

from cmrt import checkpoint
from cmrt.checkpoint import InvalidCheckpoint, cma  # pycma, imported without matplotlib (import_cma)
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
    """pycma's ``randn`` option backed by a private generator (checkpointable, unlike a lambda)."""

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)

    def __call__(self, *shape: int) -> np.ndarray:
        return self.rng.standard_normal(shape)


@dataclass
class CmaState:
    """Everything needed to continue a run bit-identically (the checkpoint: :mod:`cmrt.checkpoint`)."""

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

    def dumps(self) -> bytes:
        """The checkpoint blob stored after every generation (a data-only document, no pickle)."""
        return checkpoint.dumps(self, _CHECKPOINT_CLASSES)

    @staticmethod
    def loads(blob: bytes, settings: OptimizeSettings | None = None, *, run_id: int | None = None) -> CmaState:
        """The state in a checkpoint blob. Nothing in the blob is run; a blob that is not a valid checkpoint
        of a run with ``settings`` (when given) raises InvalidCheckpoint (a CmrtError) naming run ``run_id``."""
        try:
            state, instances = checkpoint.loads(blob, _CHECKPOINT_CLASSES)
            try:
                _check_state(state, instances, settings)
            except InvalidCheckpoint:
                raise
            except Exception as exc:  # a malformed graph the checks tripped over
                raise InvalidCheckpoint(f"malformed state ({type(exc).__name__}: {exc})"[:200]) from None
        except InvalidCheckpoint as exc:
            of = "" if run_id is None else f" of run {run_id}"
            why = " ".join(str(exc).split())
            raise InvalidCheckpoint(f"checkpoint{of} is not a valid cmrt checkpoint: {why}") from None
        return state


_CHECKPOINT_CLASSES = (CmaState, _Randn)
MAX_POPSIZE = 100_000


def _cma_options(randn: _Randn, popsize: int) -> dict:
    """The options every CMA-ES of a run is built with (a loaded checkpoint must have exactly these)."""
    return {
        "popsize": popsize,
        "seed": np.nan,
        "randn": randn,
        "verbose": -9,
        "verb_log": 0,
        "verb_disp": 0,
        "maxfevals": np.inf,  # our own budget rule decides
        "signals_filename": "",  # never read options (to evaluate) from a cma_signals.in in the cwd
    }


def _new_es(settings: OptimizeSettings, randn: _Randn, popsize: int) -> cma.CMAEvolutionStrategy:
    x0 = np.zeros(N_PARAMS) if settings.x0 is None else np.asarray(settings.x0, dtype=float)
    es = cma.CMAEvolutionStrategy(x0, settings.sigma0, _cma_options(randn, popsize))
    if settings.x0 is not None:
        es.inject([x0], force=True)  # the warm start itself is the first candidate
    return es


@functools.lru_cache(maxsize=16)
def _expected_options(popsize: int) -> tuple[dict, dict]:
    """(items, attributes) of the CMAOptions a CMA-ES of ``popsize`` has after construction."""
    opts = cma.CMAEvolutionStrategy(np.zeros(N_PARAMS), 1.0, _cma_options(_Randn(0), popsize)).opts
    return dict(opts), dict(vars(opts))


def _same(a, b) -> bool:
    """Equal with the same types all the way down (nan equals nan; functions and classes by identity)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(map(_same, a, b))
    if isinstance(a, (type(None), bool, int, str)):
        return a == b
    return a is b


def _options_differ(have: dict, want: dict, randn: _Randn) -> list[str]:
    """The keys where ``have`` differs from ``want``; ``randn`` must be the state's own generator."""
    bad = sorted(set(have) ^ set(want), key=str)
    bad += [k for k in want if k in have and not (have[k] is randn if k == "randn" else _same(have[k], want[k]))]
    return bad


def _check_state(state, instances: dict, settings: OptimizeSettings | None) -> None:
    """Refuse (InvalidCheckpoint) a loaded object graph that is not a CmaState cmrt would have written."""
    def need(ok: bool, why: str) -> None:
        if not ok:
            raise InvalidCheckpoint(why)

    need(type(state) is CmaState, "the root is not a CmaState")
    need(set(vars(state)) == {f.name for f in fields(CmaState)}, "CmaState fields differ")
    for cls in (cma.CMAEvolutionStrategy, cma.CMAOptions, _Randn, np.random.Generator):
        need(len(instances.get(cls, ())) == 1, f"not exactly one {cls.__name__}")
    randn, es = state.randn, state.es
    need(type(randn) is _Randn and set(vars(randn)) == {"rng"} and type(randn.rng) is np.random.Generator,
         "the random generator is malformed")
    need(type(es) is cma.CMAEvolutionStrategy and type(es.opts) is cma.CMAOptions, "the CMA-ES is malformed")
    need(es.sm.randn is randn, "the CMA-ES samples from another generator")
    for name in ("generation", "evaluations", "restarts"):
        need(type(getattr(state, name)) is int and getattr(state, name) >= 0, f"bad {name}")
    need(state.best_x is None or (type(state.best_x) is np.ndarray and state.best_x.shape == (N_PARAMS,)),
         "bad best_x")
    popsize = es.opts.get("popsize")
    need(type(popsize) is int and 2 <= popsize <= MAX_POPSIZE, f"bad population size {popsize!r}"[:80])
    if settings is not None:
        want = int(round(settings.popsize * settings.popsize_factor ** state.restarts))
        need(state.restarts <= settings.max_restarts and popsize == want,
             f"population {popsize} after {state.restarts} restarts, the run's settings give {want}")
    items, attrs = _expected_options(popsize)
    bad = _options_differ(dict(es.opts), items, randn) + _options_differ(vars(es.opts), attrs, randn)
    need(not bad, "CMA-ES options differ from the run's: " + ", ".join(map(str, bad))[:120])
    need(es.inputargs["inopts"] is es.inopts and not _options_differ(es.inopts, _cma_options(randn, popsize), randn),
         "CMA-ES input options differ from the run's")


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
