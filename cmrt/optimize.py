"""CMA-ES driver (pycma ask/tell) over the 8 CMRT parameters. Knows nothing of SQLite.

Stopping rules, checked between generations:

* ``threshold``: a *successful* candidate (balance held, motion performed, settled:
  ``cmrt.objective``) scores below the task's ``stop_threshold`` (ABC section 4.1);
* ``budget``: the next generation would pass ``max_evals`` evaluations;
* ``converged``: the search stalled (below) and no restart fits any more - ``max_restarts`` done, or
  less budget left than two generations of the run's population - after ``min_evals`` evaluations.
  A run never stops as converged while budget remains to search: that was the paper's slow-convergence
  stop (after 700 evaluations), which left budget unused above the threshold (push seed 13 stopped at 700
  of 1500 evaluations at 0.774, threshold 0.6).

A search *stalls* when over ``stall_generations`` generations neither its best objective nor the best
of its generation medians improved by ``stall_tol`` (relative), or pycma's own termination criteria fire.
The median matters: a population still closing in on an early lucky candidate is progressing though its
best sits still, and the best-only rule restarted such searches.

A stalled search is restarted in one of BIPOP-CMA-ES's two regimes (Hansen 2009), whichever has spent
fewer evaluations: *large* - a fresh CMA-ES from the start point and step size with the population
multiplied by ``popsize_factor`` (IPOP, Auger & Hansen 2005: it averages over the rugged landscape that
falls make) - or, once a success exists, *small* - a CMA-ES around the best candidate with a population
between half the run's and half the largest so far and a step size ``sigma0 * 10**-U`` (U uniform on
[0, 1], drawn from the run's own generator): the local search that takes a success down to the threshold.
A run whose start came from another CMRT (a warm start) has that CMRT injected as its first candidate,
and a small restart its best, so neither is lost.

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
    max_restarts: int = 30  # restarts of a stalled search (large and small regimes together)
    popsize_factor: float = 2.0  # each large restart multiplies the population by this
    bipop: bool = True  # alternate large and small restarts (BIPOP); False: large only (IPOP)


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
    median_history: list[float] = field(default_factory=list)  # the current restart's generation medians
    large_restarts: int = 0  # restarts in the large-population regime (IPOP's doubling)
    regime: str = "large"  # of the current (re)start: "large" (the first run too) or "small" (BIPOP)
    regime_evals: list[int] = field(default_factory=lambda: [0, 0])  # evaluations spent: large, small

    def dumps(self) -> bytes:
        """The checkpoint blob stored after every generation (a data-only document, no pickle). It carries
        nothing of the machine that wrote it: pycma keeps the worker's absolute working directory (its
        logger's file prefix) and wall-clock timers, which a shared store would otherwise hand to anyone; they
        are written as a fixed relative prefix and zeros (no cmrt option reads them: ``timeout`` is inf)."""
        saved = []
        try:
            for obj, name, value in _machine_fields(self.es):
                saved.append((obj, name, getattr(obj, name)))
                setattr(obj, name, value)
            return checkpoint.dumps(self, _CHECKPOINT_CLASSES)
        finally:
            for obj, name, value in reversed(saved):
                setattr(obj, name, value)

    @staticmethod
    def loads(blob: bytes, settings: OptimizeSettings | None = None, *, run_id: int | None = None) -> CmaState:
        """The state in a checkpoint blob. Nothing in the blob is run; a blob that is not a valid checkpoint
        of a run with ``settings`` (when given) raises InvalidCheckpoint (a CmrtError) naming run ``run_id``."""
        try:
            state, instances = checkpoint.loads(blob, _CHECKPOINT_CLASSES)
            if type(state) is CmaState:  # written before BIPOP (v0.3): resumes as its large regime
                for name, default in _ADDED_FIELDS.items():
                    vars(state).setdefault(name, default())
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


def _machine_fields(es) -> list[tuple[object, str, object]]:
    """(object, attribute, neutral value) of what pycma records about the host: paths and wall-clock times."""
    out = []
    logger = getattr(es, "logger", None)
    if logger is not None and isinstance(getattr(logger, "name_prefix", None), str):
        out.append((logger, "name_prefix", "outcmaes/"))
    for timer in (getattr(es, "timer", None), getattr(logger, "timer_plot", None), getattr(logger, "timer_all", None)):
        for name in ("paused", "last_tic", "_last_toc", "_time_at_reset", "_time_at_creation"):
            if isinstance(getattr(timer, name, None), float):
                out.append((timer, name, 0.0))
    return out


_CHECKPOINT_CLASSES = (CmaState, _Randn)
_ADDED_FIELDS = {"median_history": list, "large_restarts": lambda: 0, "regime": lambda: "large",
                 "regime_evals": lambda: [0, 0]}
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


def _new_es(settings: OptimizeSettings, randn: _Randn, popsize: int,
            sigma: float | None = None) -> cma.CMAEvolutionStrategy:
    x0 = np.zeros(N_PARAMS) if settings.x0 is None else np.asarray(settings.x0, dtype=float)
    es = cma.CMAEvolutionStrategy(x0, settings.sigma0 if sigma is None else sigma, _cma_options(randn, popsize))
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
    need(type(state.large_restarts) is int and 0 <= state.large_restarts <= state.restarts, "bad large_restarts")
    need(state.regime in REGIMES, "bad regime")
    need(type(state.regime_evals) is list and len(state.regime_evals) == 2
         and all(type(n) is int and 0 <= n <= state.evaluations for n in state.regime_evals), "bad regime_evals")
    if settings is not None:
        large = _large_popsize(settings, state.large_restarts)
        ok = popsize == large if state.regime == "large" else (
            settings.popsize // 2 <= popsize <= max(settings.popsize, large // 2))
        need(state.restarts <= settings.max_restarts and ok,
             f"population {popsize} in the {state.regime} regime after {state.large_restarts} large restarts, "
             f"the run's settings give {large}")
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
    state.median_history.append(float(np.median(objectives)))
    state.regime_evals[REGIMES.index(state.regime)] += len(xs)
    gen_best = min(objectives)
    state.restart_history.append(min(gen_best, state.restart_history[-1]) if state.restart_history else gen_best)
    return xs, records


def _flat(old: float, new: float, tol: float) -> bool:
    return old - new <= tol * max(abs(old), 1e-12)


def _stalled(state: CmaState, settings: OptimizeSettings) -> str | None:
    """Why the current (re)start has stopped making progress, or None.

    Progress is the search's own: over the last ``stall_generations`` generations neither its best nor
    the best of its generation *medians* improved by ``stall_tol`` (relative). A best that sits still while
    the population's median keeps falling is a search closing in on a lucky early candidate, not a stall
    (on rise seeds 11 and 13 the best-only rule restarted such searches; the search left alone found its
    first success hundreds of evaluations earlier). pycma's own termination criteria count as a stall too."""
    h, m, g = state.restart_history, state.median_history, settings.stall_generations
    if len(h) > g and len(m) > g and _flat(h[-g - 1], h[-1], settings.stall_tol) \
            and _flat(min(m[:-g]), min(m[-g:]), settings.stall_tol):
        return "converged"
    cma_stop = {k: v for k, v in state.es.stop().items() if k != "maxfevals"}
    if cma_stop:
        return "converged:" + ",".join(sorted(cma_stop))
    return None


REGIMES = ("large", "small")


def _large_popsize(settings: OptimizeSettings, large_restarts: int) -> int:
    return int(round(settings.popsize * settings.popsize_factor ** large_restarts))


def _next_regime(state: CmaState, settings: OptimizeSettings) -> str | None:
    """The regime of the next restart, or None when the stalled search should stop instead.

    BIPOP (Hansen 2009): the regime that has spent fewer evaluations goes next - a large restart (IPOP:
    the population grows by ``popsize_factor``, which averages over the rugged landscape falls make) or a
    small one (a small population and step size around the best candidate so far: the local search that
    takes a success down to the threshold). None when no restart fits: ``max_restarts`` done, or less budget
    left than two generations of the run's population; only then may a stalled run stop as converged
    (:func:`stop_reason`), so a run never stops while budget remains to search."""
    left = settings.max_evals - state.evaluations
    if state.restarts >= settings.max_restarts or left < 2 * settings.popsize:
        return None
    large_fits = left >= 2 * _large_popsize(settings, state.large_restarts + 1)
    if not settings.bipop:
        return "large" if large_fits else None
    # a small restart refines a success (around the best one); before the first success there is nothing to refine
    small_turn = state.best_success_objective < np.inf and state.regime_evals[1] < state.regime_evals[0]
    if small_turn or (not large_fits and state.best_success_objective < np.inf):
        return "small"
    return "large" if large_fits else None


def stop_reason(state: CmaState, settings: OptimizeSettings) -> str | None:
    """Why the run should stop now (threshold, budget, converged...), or None to go on."""
    if state.best_success_objective < settings.stop_threshold:
        return "threshold"
    if state.evaluations >= settings.max_evals or (
            state.evaluations and state.evaluations + popsize_of(state) > settings.max_evals):
        return "budget"  # never past max_evals, but at least one generation
    why = _stalled(state, settings)
    if why and state.evaluations >= settings.min_evals and _next_regime(state, settings) is None:
        return why  # the paper's slow-convergence stop, only once no restart fits (never before min_evals)
    return None


def restart_if_stalled(state: CmaState, settings: OptimizeSettings) -> bool:
    """After a generation: restart a stalled search (BIPOP regimes, :func:`_next_regime`) unless it should
    stop. Called before the checkpoint is written, so a resumed run sees the restart as it happened."""
    if state.best_success_objective < settings.stop_threshold or not _stalled(state, settings):
        return False
    regime = _next_regime(state, settings)
    if regime is None:
        return False
    if regime == "large":
        state.large_restarts += 1
        state.es = _new_es(settings, state.randn, _large_popsize(settings, state.large_restarts))
    else:  # Hansen's small regime, drawn from the run's own generator (checkpointed: a resume draws the same)
        u = float(state.randn.rng.random())
        large = _large_popsize(settings, state.large_restarts)
        popsize = max(settings.popsize // 2, int(settings.popsize * (0.5 * large / settings.popsize) ** (u * u)))
        sigma = settings.sigma0 * 10.0 ** (-u)
        state.es = _new_small_es(settings, state, popsize, sigma)
    state.regime = regime
    state.restarts += 1
    state.restart_history = []
    state.median_history = []
    return True


def _new_small_es(settings: OptimizeSettings, state: CmaState, popsize: int,
                  sigma: float) -> cma.CMAEvolutionStrategy:
    """A small-regime CMA-ES around the best candidate so far (injected as its first candidate)."""
    x = np.asarray(state.best_x, dtype=float)
    es = cma.CMAEvolutionStrategy(x, sigma, _cma_options(state.randn, popsize))
    es.inject([x], force=True)
    return es


def best_cmrt(state: CmaState, clip_s: float) -> Cmrt:
    """The best candidate so far as a CMRT."""
    return Cmrt.from_params(state.best_x, clip_s)
