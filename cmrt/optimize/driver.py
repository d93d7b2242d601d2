"""CMA-ES driver (pycma ask/tell) over the 8 CMRT parameters (12 in x and y: ``OptimizeSettings.n_params``).
Knows nothing of SQLite.

Stopping rules, checked between generations:

* ``threshold``: a *successful* candidate (balance held, motion performed, settled:
  ``cmrt.sim.objective``) scores below the task's ``stop_threshold`` (ABC section 4.1);
* ``budget``: the next generation would pass ``max_evals`` evaluations;
* ``converged``: the search stalled (below) and no restart fits any more - ``max_restarts`` done, or
  less budget left than two generations of the run's population - after ``min_evals`` evaluations.
  A run never stops as converged while budget remains to search: that was the paper's slow-convergence
  stop (after 700 evaluations), which left budget unused above the threshold (push seed 13 stopped at 700
  of 1500 evaluations at 0.774, threshold 0.6).

A search *stalls* when over ``stall_generations`` generations its best objective did not improve by
``stall_tol`` (relative) and - until the run's first success - neither did the best of its generation
medians, or when pycma's own termination criteria fire (``stall_rule="hybrid"``). Before a success the
median matters: a population still closing in on an early lucky candidate is progressing though its best
sits still, and the best-only rule restarted such searches. After it, a success the search no longer
improves is what a small restart is for, whatever the rest of the population does; waiting for the median
too (``"median"``, v0.4) kept warm-started rise runs and push runs sliding for their whole budget.

A stalled search is restarted in one of BIPOP-CMA-ES's two regimes (Hansen 2009), whichever has spent
fewer evaluations: *large* - a fresh CMA-ES from the start point and step size with the population
multiplied by ``popsize_factor`` (IPOP, Auger & Hansen 2005: it averages over the rugged landscape that
falls make) - or, once a success exists, *small* - a CMA-ES around the best candidate with a population
between half the run's and half the largest so far and a step size ``sigma0 * 10**-U`` (U uniform on
[0, 1], drawn from the run's own generator): the local search that takes a success down to the threshold.
A run whose start came from another CMRT (a warm start) has that CMRT injected as its first candidate,
and a small restart its best, so neither is lost. IPOP's doubling stops at ``MAX_RESTART_POPSIZE`` (1280).

Determinism: pycma seeds numpy's *global* RNG unless told otherwise; we pass
``seed=nan`` and our own ``randn`` drawing from a private ``numpy.random.Generator``
seeded by the run's seed; restarts keep drawing from the same generator. The whole
:class:`CmaState` (pycma object + generator + bookkeeping) is checkpointed after every
generation, so a resumed run continues - across restarts too - with exactly the
samples an uninterrupted one would draw.

Checkpoints are untrusted input (a store is shared and downloaded), so they are not
pickles but :mod:`cmrt.optimize.checkpoint` documents, from which nothing is called, and
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
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields

import numpy as np

from cmrt.motion.curve import N_KNOTS, N_PARAMS_TWO_AXES, Cmrt
from cmrt.optimize import checkpoint
from cmrt.optimize.checkpoint import InvalidCheckpoint, cma  # pycma, imported without matplotlib (import_cma)
from cmrt.optimize.settings import STALL_RULES, OptimizeSettings  # noqa: F401 (re-exported: the driver's settings)
from cmrt.sim.objective import EvalRecord

N_PARAMS = 2 * N_KNOTS
DIMENSIONS = (N_PARAMS, N_PARAMS_TWO_AXES)  # a CMRT's parameters in one axis or two (cmrt.motion.curve)
_log = logging.getLogger(__name__)


class _Randn:
    """pycma's ``randn`` option backed by a private generator (checkpointable, unlike a lambda)."""

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)

    def __call__(self, *shape: int) -> np.ndarray:
        return self.rng.standard_normal(shape)


@dataclass
class CmaState:
    """Everything needed to continue a run bit-identically (the checkpoint: :mod:`cmrt.optimize.checkpoint`)."""

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
    # the zero CMRT's objective when it is a success (``know_zero``): a threshold stop needs a better success, so
    # a run never stops on, or reports, something worse than no CMRT at all (inf: the zero CMRT fails, or a
    # run from before the zero CMRT was a known candidate)
    zero_success_objective: float = float("inf")

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
                 "regime_evals": lambda: [0, 0], "zero_success_objective": lambda: float("inf")}
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
    x0 = np.zeros(settings.n_params) if settings.x0 is None else np.asarray(settings.x0, dtype=float)
    es = cma.CMAEvolutionStrategy(x0, settings.sigma0 if sigma is None else sigma, _cma_options(randn, popsize))
    if settings.x0 is not None:
        es.inject([x0], force=True)  # the warm start itself is the first candidate
    return es


@functools.lru_cache(maxsize=16)
def _fresh_es(popsize: int, n_params: int = N_PARAMS) -> cma.CMAEvolutionStrategy:
    """A CMA-ES of ``popsize`` in ``n_params`` dimensions as cmrt builds it (never stepped): what a loaded one's
    constants must equal."""
    return cma.CMAEvolutionStrategy(np.zeros(n_params), 1.0, _cma_options(_Randn(0), popsize))


def _expected_options(popsize: int, n_params: int = N_PARAMS) -> tuple[dict, dict]:
    """(items, attributes) of the CMAOptions a CMA-ES of ``popsize`` has after construction."""
    opts = _fresh_es(popsize, n_params).opts
    return dict(opts), dict(vars(opts))


#: the parts of a CMA-ES that depend only on its dimension and population: in a checkpoint their scalar
#: attributes (and the recombination weights) must equal a fresh CMA-ES's. A forged constant is how a
#: checkpoint that passes the structural checks exhausts memory (``_stoptolxstagnation.time_delta_expo =
#: 10**18`` grows an integer without bound at the first ``stop()``).
_CONSTANT_PARTS = ("sp", "sp0", "sp.weights", "const", "_stoptolxstagnation", "adapt_sigma", "sm", "gp",
                   "boundary_handler", "sigma_vec")
#: scalar attributes of those parts that are state, not constants (counters and iteration marks)
_STATE_SCALARS = {"_stoptolxstagnation": {"count", "count_x"}, "adapt_sigma": {"_ps_updated_iteration", "delta"},
                  "sm": {"count_eigen", "count_tell", "last_update"}}
#: pycma's own cap on its long fitness histories (``fit.histbest``, ``fit.histmedian``: 2e4 entries)
_HISTORY_CAP = 20_000
_MAX_COUNTER = 2**40


def _part(es, dotted: str):
    for name in dotted.split("."):
        es = getattr(es, name)
    return es


def _scalars(obj) -> dict:
    return {k: v for k, v in vars(obj).items() if type(v) in (bool, int, float)}


def _bounds_broken(state: CmaState, popsize: int) -> str | None:
    """Why the loaded CMA-ES implies more work or memory than a run of ``popsize`` ever has, or None.

    Checked: its constants against a fresh CMA-ES's (:data:`_CONSTANT_PARTS`); every list, tuple, dict and
    array reachable from it against what ``popsize`` needs (a generation's candidates, N x N matrices,
    pycma's capped histories) - 6,000 references in ``pop_injection_solutions`` would ask for 6,000 clips
    in one batch, 300,000 archive entries make every ``tell`` quadratic; and its iteration and evaluation
    counters against the run's own."""
    es = state.es
    fresh = _fresh_es(popsize, es.N)
    for dotted in _CONSTANT_PARTS:
        have, want = _scalars(_part(es, dotted)), _scalars(_part(fresh, dotted))
        skip = _STATE_SCALARS.get(dotted, set())
        bad = sorted(k for k in set(have) | set(want) if k not in skip and not _same(have.get(k), want.get(k)))
        if bad:
            return f"CMA-ES constant {dotted}.{bad[0]} is not a population-{popsize} CMA-ES's"
    if list(es.sp.weights) != list(fresh.sp.weights):
        return f"CMA-ES recombination weights are not a population-{popsize} CMA-ES's"
    if not (es.countiter <= state.generation and es.countevals <= state.evaluations):
        return "CMA-ES counters exceed the run's generations or evaluations"
    limit = es.N * max(popsize, es.N) + 256
    seen: set[int] = set()
    todo: list[tuple[object, str]] = [(es, "es")]
    while todo:
        obj, path = todo.pop()
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        if type(obj) is int and not -_MAX_COUNTER <= obj <= _MAX_COUNTER:
            return f"CMA-ES integer {path} is out of range"
        if isinstance(obj, np.ndarray):
            if obj.size > limit:
                return f"CMA-ES array {path} has {obj.size} entries, more than a population-{popsize} run holds"
            continue
        if isinstance(obj, (list, tuple, dict)):
            cap = _HISTORY_CAP if path in ("es.fit.histbest", "es.fit.histmedian") else limit
            if len(obj) > cap:
                return f"CMA-ES container {path} has {len(obj)} entries, more than a population-{popsize} run holds"
            items = obj.items() if isinstance(obj, dict) else enumerate(obj)
            todo.extend((v, f"{path}[]") for _, v in items)
        if type(obj).__module__.startswith("cma") and hasattr(obj, "__dict__"):
            todo.extend((v, f"{path}.{k}") for k, v in vars(obj).items())
    return None


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
    need(type(es.N) is int and es.N in DIMENSIONS, "the CMA-ES's dimension is not a CMRT's")
    need(settings is None or es.N == settings.n_params, "the CMA-ES's dimension is not the run's CMRT's")
    need(state.best_x is None or (type(state.best_x) is np.ndarray and state.best_x.shape == (es.N,)),
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
    broken = _bounds_broken(state, popsize)
    need(broken is None, broken or "")
    items, attrs = _expected_options(popsize, es.N)
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


ZERO_X = np.zeros(N_PARAMS)  # the zero CMRT in the optimizer's parameters: no displacement at any time


def know_zero(state: CmaState, record: EvalRecord) -> None:
    """The zero CMRT (``ZERO_X``), scored by the run's own evaluator before the first generation, as a candidate
    the search knows: the run's best is never worse than no CMRT, and a threshold stop needs a success better
    than it. Not counted as an evaluation (the budget and every generation are as without it)."""
    if record.objective < state.best_objective:
        state.best_x, state.best_objective = np.zeros(state.es.N), record.objective
        state.best_fell, state.best_success = record.fell, record.success
    if record.success:
        state.best_success_objective = min(state.best_success_objective, record.objective)
        state.zero_success_objective = record.objective


def _threshold_met(state: CmaState, settings: OptimizeSettings) -> bool:
    """A success below the threshold that beats the zero CMRT (when the zero CMRT is a success itself)."""
    return state.best_success_objective < min(settings.stop_threshold, state.zero_success_objective)


def _flat(old: float, new: float, tol: float) -> bool:
    return old - new <= tol * max(abs(old), 1e-12)


def _stalled(state: CmaState, settings: OptimizeSettings) -> str | None:
    """Why the current (re)start has stopped making progress, or None.

    Progress is the search's own: over the last ``stall_generations`` generations its best did not improve
    by ``stall_tol`` (relative) and, while the run has no success yet (``stall_rule="hybrid"``), neither did
    the best of its generation *medians*. Before a success, a best that sits still while the median keeps
    falling is a search closing in on a lucky early candidate, not a stall (on rise seeds 11 and 13 the
    best-only rule restarted such searches). After one, a best that sits still is a success to refine by a
    small restart: with the median test kept (``"median"``), push seeds 13 and 14 and rise warm start 14
    (tuning seeds) slid to the end of their budget above the threshold; refined, all three reach it.
    pycma's own termination criteria count as a stall too."""
    h, m, g = state.restart_history, state.median_history, settings.stall_generations
    rule = settings.stall_rule
    median_counts = rule == "median" or (rule == "hybrid" and state.best_success_objective == np.inf)
    if len(h) > g and len(m) > g and _flat(h[-g - 1], h[-1], settings.stall_tol) \
            and (not median_counts or _flat(min(m[:-g]), min(m[-g:]), settings.stall_tol)):
        return "converged"
    cma_stop = {k: v for k, v in state.es.stop().items() if k != "maxfevals"}
    if cma_stop:
        return "converged:" + ",".join(sorted(cma_stop))
    return None


REGIMES = ("large", "small")


#: the largest population IPOP's doubling reaches (10 x 2**7; ``--popsize`` above it is kept as given). Past it a
#: generation costs more than the default budget and averages no better; it also bounds a generation's
#: optimizer memory (a batch's clips are bounded separately: :mod:`cmrt.optimize.memory`).
MAX_RESTART_POPSIZE = 1280


def _large_popsize(settings: OptimizeSettings, large_restarts: int) -> int:
    grown = int(round(settings.popsize * settings.popsize_factor ** min(large_restarts, 64)))
    return grown if large_restarts == 0 else min(grown, max(settings.popsize, MAX_RESTART_POPSIZE))


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
    if _threshold_met(state, settings):
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
    if _threshold_met(state, settings) or not _stalled(state, settings):
        return False
    regime = _next_regime(state, settings)
    if regime is None:
        return False
    if regime == "large":
        state.large_restarts += 1
        popsize = _large_popsize(settings, state.large_restarts)
        if popsize < settings.popsize * settings.popsize_factor ** min(state.large_restarts, 64):
            _log.info("large restart %d: population capped at %d (MAX_RESTART_POPSIZE)", state.large_restarts, popsize)
        state.es = _new_es(settings, state.randn, popsize)
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
