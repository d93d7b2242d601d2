"""The project's optimizer against what a user would pick instead: same evaluator, budget, verdict and start.

    python tools/peer_benchmark.py --tasks rise,push --seeds 41-60 [--optimizers ...] [--targets 0.9,0.8]
                                   [--max-evals 3000] [--json]

Every run starts from the flat CMRT - its first evaluation, for every optimizer - is scored by the batched
evaluator (``cmrt.Evaluator``) with the task's ``success`` flag, and goes on to the whole budget (no threshold
stop: the best-so-far after every evaluation is recorded). Optimizers (``--optimizers``, comma-separated; all by
default):

* ``cmrt``: ``cmrt.optimize_now(task, init="none", seed=S)`` - the project's driver with its defaults (step size
  0.5, population 10, BIPOP restarts on stagnation), the task's stop threshold set to 0;
* ``optuna``: optuna's ``CmaEsSampler`` through its current API (no ``x0``/``sigma0``, deprecated since 4.9):
  the search box +-``BOX`` parameter units, its own step size (a sixth of the box), the flat CMRT enqueued as
  its first trial and told before any other is asked (so the CMA-ES, not the random start-up sampler, draws
  every later trial), generations of the project's population, no restarts (optuna offers none);
* ``optuna-tpe``: optuna's multivariate ``TPESampler`` (a Bayesian optimizer of another family: a tree-structured
  Parzen estimator; ``constant_liar`` for the generation asked before it is told), the same box and first trial,
  generations of the project's population;
* ``cmaes``: the ``cmaes`` library's ``CMA`` from the flat CMRT with the project's step size and population,
  restarted IPOP-style (population doubled) on stagnation - its own ``should_stop()``, or the best not improved
  by 0.1 % over ``STALL_GENERATIONS`` generations (``should_stop`` alone never fired on these objectives);
* ``cmaes-lra``: the same with learning-rate adaptation (``lr_adapt=True``, LRA-CMA-ES, Nomura et al. 2023:
  made for multimodal and noisy problems);
* ``pycma-bipop``: pycma's ``fmin2`` with BIPOP restarts (Hansen 2009), the same start, step size and first
  population, whole generations evaluated as one batch;
* ``pycma-lq``: pycma's surrogate-assisted lq-CMA-ES (``fmin_lq_surr2``, Hansen 2019: a linear-quadratic model
  of the objective decides which candidates are evaluated), the same start, step size and population, IPOP
  restarts; it evaluates one candidate at a time, so each evaluation is a generation of its own;
* ``random``: independent draws from N(0, sigma^2 I) around the flat CMRT.

The measure (``ert``): the expected running time to a target - the evaluations (and generations: evaluator
calls, which wall time follows with batched evaluation) all runs spent until each reached the target, a run that
never did charged the whole budget, over the number of runs that did (Hansen et al., COCO) - for the first
physical success and for each objective target of ``--targets`` (fix them on tuning seeds; report on others),
with a 95 % bootstrap interval over the seeds (``BOOTSTRAP`` resamples). ``comparison`` gives, per task and
target, the project's ERT over the best peer's with its bootstrap interval. Optuna and cmaes are test extras
(``pip install -e .[test]``), not runtime dependencies.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from cmrt import CmrtError, Evaluator, OptimizeSettings, Task, open_store, optimize_now, resolve_task
from cmrt.optimize.driver import N_PARAMS

OPTIMIZERS = ("cmrt", "optuna", "optuna-tpe", "cmaes", "cmaes-lra", "pycma-bipop", "pycma-lq", "random")
BOX = 10.0  # optuna's search box, +- parameter units (+-0.5 m of CoM shift): wider than any shipped CMRT (<= 7.5)
STALL_GENERATIONS = 20  # the cmaes peers restart when the best improved < 0.1 % over this many generations (the
STALL_IMPROVEMENT = 1e-3  # project's own stagnation rule, OptimizeSettings.stall_generations)
BOOTSTRAP = 2000  # resamples of the seeds for an ERT's interval
SUCCESS = "success"  # the target that is the first physical success, not an objective value


class BudgetSpent(Exception):
    """The budget ended inside a library's loop (pycma's fmin2 asks for whole generations)."""


class Budget:
    """Counts a run's evaluations and generations (evaluator calls) and records the best objective so far after
    every evaluation and the first success."""

    def __init__(self, task: Task, evaluator: Evaluator | None, max_evals: int):
        self.task, self.evaluator, self.max_evals = task, evaluator, max_evals
        self.best_so_far: list[float] = []  # after each evaluation
        self.generation_of: list[int] = []  # the evaluator call (1, 2, ...) each evaluation came in
        self.generations = 0
        self.first_success: int | None = None  # evaluations up to and including the first success
        self.best_success = False

    @property
    def evaluations(self) -> int:
        return len(self.best_so_far)

    @property
    def done(self) -> bool:
        return self.evaluations >= self.max_evals

    def __call__(self, xs: list[np.ndarray]) -> list[float]:
        xs = xs[: self.max_evals - self.evaluations]
        records = self.evaluator(self.task, xs) if xs else []
        self.generations += bool(records)
        for r in records:
            self.note(r.objective, r.success)
        return [r.objective for r in records]

    def note(self, objective: float, success: bool, generation: int | None = None) -> None:
        best = min(self.best_so_far[-1], objective) if self.best_so_far else objective
        if objective == best:
            self.best_success = success
        self.best_so_far.append(best)
        self.generation_of.append(self.generations if generation is None else generation)
        if success and self.first_success is None:
            self.first_success = self.evaluations

    def start(self) -> None:
        """The start every optimizer shares, evaluated first: the flat CMRT (one generation of its own)."""
        self([np.zeros(N_PARAMS)])

    def reached(self, target: float | str) -> tuple[int, int] | None:
        """(evaluations, generations) spent when the target was first reached, or None."""
        if target == SUCCESS:
            k = self.first_success
        else:
            hits = np.flatnonzero(np.asarray(self.best_so_far) <= float(target))
            k = int(hits[0]) + 1 if hits.size else None
        return None if k is None else (k, self.generation_of[k - 1])


def run_cmrt(budget: Budget, seed: int, sigma: float, popsize: int) -> dict:
    """The project's own driver, as ``cmrt optimize --init none`` runs it, to the whole budget."""
    with tempfile.TemporaryDirectory() as tmp, open_store(Path(tmp) / "run.sqlite") as store:
        run = optimize_now(store, budget.task, budget.evaluator, seed=seed, init="none",
                           max_evals=budget.max_evals - 1, progress=False)
        budget.note(run.baseline_objective, bool(run.baseline_success), generation=1)  # the driver knows the flat
        for e in sorted(store.evaluations(run.id), key=lambda e: (e.gen, e.idx)):  # CMRT's score first
            budget.note(e.objective, bool(e.success), generation=e.gen + 2)
        budget.generations = run.generations + 1
    return {"stop_reason": run.stop_reason, "restarts": run.restarts}


def run_optuna(budget: Budget, seed: int, sigma: float, popsize: int, box: float = BOX, tpe: bool = False) -> dict:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.ERROR)
    sampler = (optuna.samplers.TPESampler(seed=seed, multivariate=True, constant_liar=True) if tpe
               else optuna.samplers.CmaEsSampler(seed=seed, popsize=popsize))
    study = optuna.create_study(sampler=sampler, direction="minimize")
    dists = {f"u{i}": optuna.distributions.FloatDistribution(-box, box) for i in range(N_PARAMS)}
    study.enqueue_trial({f"u{i}": 0.0 for i in range(N_PARAMS)})  # the flat CMRT first, told alone
    first = True
    while not budget.done:
        n = 1 if first else min(popsize, budget.max_evals - budget.evaluations)
        trials = [study.ask(dists) for _ in range(n)]
        xs = [np.array([t.params[f"u{i}"] for i in range(N_PARAMS)]) for t in trials]
        for t, f in zip(trials, budget(xs), strict=True):
            study.tell(t, f)
        first = False
    return {"first_trial": [study.trials[0].params[f"u{i}"] for i in range(N_PARAMS)]}


def _cmaes(budget: Budget, seed: int, sigma: float, popsize: int, lr_adapt: bool) -> dict:
    from cmaes import CMA

    rng = np.random.default_rng(seed)
    restarts = 0
    budget.start()
    while not budget.done:
        opt = CMA(mean=np.zeros(N_PARAMS), sigma=sigma, population_size=popsize * 2**restarts,
                  seed=int(rng.integers(1, 2**31 - 1)), lr_adapt=lr_adapt)
        history: list[float] = []
        while not budget.done and not opt.should_stop():
            xs = [opt.ask() for _ in range(opt.population_size)]
            fs = budget(xs)
            if len(fs) < len(xs):
                break  # the budget ended inside the generation
            opt.tell(list(zip(xs, fs, strict=True)))
            history.append(budget.best_so_far[-1])
            if len(history) > STALL_GENERATIONS and (
                    history[-STALL_GENERATIONS - 1] - history[-1] < STALL_IMPROVEMENT * abs(history[-1])):
                break  # stagnation: restart with a doubled population (IPOP)
        restarts += 1
    return {"restarts": restarts - 1}


def run_cmaes(budget: Budget, seed: int, sigma: float, popsize: int) -> dict:
    return _cmaes(budget, seed, sigma, popsize, lr_adapt=False)


def run_cmaes_lra(budget: Budget, seed: int, sigma: float, popsize: int) -> dict:
    return _cmaes(budget, seed, sigma, popsize, lr_adapt=True)


def run_pycma_bipop(budget: Budget, seed: int, sigma: float, popsize: int) -> dict:
    import cma

    def objective(xs: list) -> list[float]:
        fs = budget([np.asarray(x, float) for x in xs])
        if len(fs) < len(xs):
            raise BudgetSpent
        return fs

    state = np.random.get_state()  # pycma seeds numpy's global generator: leave it as it was
    budget.start()
    try:
        cma.fmin2(None, np.zeros(N_PARAMS), sigma, parallel_objective=objective, restarts=50, bipop=True,
                  options={"popsize": popsize, "seed": seed, "maxfevals": budget.max_evals, "verbose": -9,
                           "verb_log": 0, "verb_disp": 0, "tolfun": 1e-11})
    except BudgetSpent:
        pass
    finally:
        np.random.set_state(state)
    return {}  # fmin2 may end before the budget (its restarts spent): ``_spent`` charges the rest


def run_pycma_lq(budget: Budget, seed: int, sigma: float, popsize: int) -> dict:
    import cma

    def objective(x) -> float:
        fs = budget([np.asarray(x, float)])
        if not fs:
            raise BudgetSpent
        return fs[0]

    state = np.random.get_state()  # pycma seeds numpy's global generator: leave it as it was
    budget.start()
    try:
        cma.fmin_lq_surr2(objective, np.zeros(N_PARAMS), sigma, restarts=9, incpopsize=2,
                          options={"popsize": popsize, "seed": seed, "maxfevals": budget.max_evals, "verbose": -9,
                                   "verb_log": 0, "verb_disp": 0})
    except BudgetSpent:
        pass
    finally:
        np.random.set_state(state)
    return {}


def run_random(budget: Budget, seed: int, sigma: float, popsize: int) -> dict:
    rng = np.random.default_rng(seed)
    budget.start()
    while not budget.done:
        budget(list(sigma * rng.standard_normal((popsize, N_PARAMS))))
    return {}


RUNNERS: dict[str, Callable[[Budget, int, float, int], dict]] = {
    "cmrt": run_cmrt, "optuna": run_optuna, "cmaes": run_cmaes, "cmaes-lra": run_cmaes_lra,
    "pycma-bipop": run_pycma_bipop, "pycma-lq": run_pycma_lq, "random": run_random}


def ert(spent: np.ndarray, hit: np.ndarray) -> float:
    """Expected running time: what every run spent (to its hit, or its whole budget) over the runs that hit."""
    return float(spent.sum() / hit.sum()) if hit.any() else math.inf


def ert_with_interval(spent: np.ndarray, hit: np.ndarray, rng: np.random.Generator) -> tuple[float, list[float]]:
    """The ERT and its 95 % bootstrap interval over the runs (seeds)."""
    n = spent.size
    picks = rng.integers(0, n, size=(BOOTSTRAP, n))
    samples = np.array([ert(spent[p], hit[p]) for p in picks])
    return ert(spent, hit), _interval(samples)


def _interval(samples: np.ndarray) -> list[float]:
    """The central 95 % of bootstrap samples, without interpolating (an unreached target's ERT is inf)."""
    kept = samples[~np.isnan(samples)]
    if kept.size == 0:
        return [math.nan, math.nan]
    return [float(np.quantile(kept, 0.025, method="lower")), float(np.quantile(kept, 0.975, method="higher"))]


def _charged(b: Budget, which: int) -> float:
    """What a run that never reached a target is charged: the whole budget (a run that ended early, its
    generations scaled up to the budget)."""
    if which == 0:
        return float(b.max_evals)
    return b.generations * b.max_evals / max(b.evaluations, 1)


def _spent(runs: list[Budget], target: float | str, which: int) -> tuple[np.ndarray, np.ndarray]:
    """Per run: what it spent until it reached the target, or the whole budget (``which``: 0 evaluations, 1
    generations), and whether it reached it."""
    reached = [b.reached(target) for b in runs]
    spent = np.array([r[which] if r else _charged(b, which) for r, b in zip(reached, runs, strict=True)], float)
    return spent, np.array([r is not None for r in reached])


def summarize(task: Task, optimizer: str, runs: list[Budget], extras: list[dict], seeds: list[int],
              targets: list[float | str], rng: np.random.Generator) -> dict:
    table = {}
    for target in targets:
        row = {}
        for which, unit in ((0, "evals"), (1, "generations")):
            spent, hit = _spent(runs, target, which)
            value, interval = ert_with_interval(spent, hit, rng)
            row[unit], row[f"{unit}_ci"] = value, interval
        row["reached"] = int(hit.sum())
        table[str(target)] = row
    return {
        "task": task.name, "speed": task.speed, "optimizer": optimizer, "ert": table,
        "runs": [{"seed": s, "evaluations": b.evaluations, "generations": b.generations,
                  "first_success_evals": b.first_success, "first_objective": b.best_so_far[0] if b.best_so_far
                  else None, "best_objective": b.best_so_far[-1] if b.best_so_far else None,
                  "best_success": b.best_success, **x}
                 for s, b, x in zip(seeds, runs, extras, strict=True)],
    }


def _ratio(mine: float, peer: float) -> float:
    """The project's ERT over a peer's; 0 when only the project reaches the target, inf when only the peer does,
    NaN when neither does."""
    if math.isinf(mine) and math.isinf(peer):
        return math.nan
    return 0.0 if math.isinf(peer) else (math.inf if math.isinf(mine) else mine / peer)


def compare(rows: list[dict], targets: list[float | str], rng: np.random.Generator) -> list[dict]:
    """Per task and target: the project's ERT (evaluations) over the best peer's, with a bootstrap interval (the
    two optimizers' seeds resampled independently)."""
    out = []
    for task in dict.fromkeys(r["task"] for r in rows):
        mine = next((r for r in rows if r["task"] == task and r["optimizer"] == "cmrt"), None)
        peers = [r for r in rows if r["task"] == task and r["optimizer"] != "cmrt"]
        if mine is None or not peers:
            continue
        for target in map(str, targets):
            best = min(peers, key=lambda r: r["ert"][target]["evals"])
            (sa, ha), (sb, hb) = mine["_spent"][target], best["_spent"][target]
            ratios = []
            for _ in range(BOOTSTRAP):
                pa, pb = rng.integers(0, sa.size, sa.size), rng.integers(0, sb.size, sb.size)
                ratios.append(_ratio(ert(sa[pa], ha[pa]), ert(sb[pb], hb[pb])))
            out.append({"task": task, "target": target, "best_peer": best["optimizer"],
                        "ratio": _ratio(mine["ert"][target]["evals"], best["ert"][target]["evals"]),
                        "ratio_ci": _interval(np.array(ratios))})
    return out


def benchmark(tasks: list[Task], optimizers: list[str], seeds: list[int], max_evals: int,
              targets: list[float | str], progress: bool = False, optuna_box: float = BOX) -> dict:
    rows = []
    popsize, sigma = OptimizeSettings().popsize, OptimizeSettings().sigma0  # the project's, for every peer
    rng = np.random.default_rng(0)  # the bootstrap's
    with Evaluator("batch") as ev:
        for task in tasks:
            unstopped = task.with_params(stop_threshold=0.0)  # every run to its whole budget
            for name in optimizers:
                runs, extras = [], []
                for seed in seeds:
                    t0 = time.perf_counter()
                    budget = Budget(unstopped, ev, max_evals)
                    extra = (run_optuna(budget, seed, sigma, popsize, optuna_box, tpe=name == "optuna-tpe")
                             if name.startswith("optuna") else RUNNERS[name](budget, seed, sigma, popsize))
                    extras.append({**extra, "wall_s": round(time.perf_counter() - t0, 2)})
                    runs.append(budget)
                    if progress:
                        print(json.dumps({"task": task.name, "optimizer": name, "seed": seed,
                                          "first_success_evals": budget.first_success,
                                          "best_objective": budget.best_so_far[-1], **extras[-1]}),
                              file=sys.stderr, flush=True)
                row = summarize(task, name, runs, extras, seeds, targets, rng)
                row["_spent"] = {str(t): _spent(runs, t, 0) for t in targets}
                rows.append(row)
    comparison = compare(rows, targets, rng)
    for row in rows:
        del row["_spent"]
    return {"max_evals": max_evals, "seeds": seeds, "popsize": popsize, "sigma0": sigma, "optuna_box": optuna_box,
            "targets": [str(t) for t in targets], "rows": rows, "comparison": comparison,
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"}


def parse_seeds(text: str) -> list[int]:
    seeds: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        seeds.extend(range(int(lo), int(hi or lo) + 1))
    return seeds


def _text(result: dict) -> str:
    lines = [f"{len(result['seeds'])} seeds, budget {result['max_evals']} evaluations, population "
             f"{result['popsize']}; ERT in evaluations [95 % bootstrap interval] (reached/seeds)"]
    for r in result["rows"]:
        speed = f" {r['speed']:g}" if r["speed"] is not None else ""
        cells = [f"{t}: {v['evals']:.0f} [{v['evals_ci'][0]:.0f}, {v['evals_ci'][1]:.0f}] ({v['reached']}/"
                 f"{len(r['runs'])})" for t, v in r["ert"].items()]
        lines.append(f"{r['task'] + speed:10} {r['optimizer']:12} " + "; ".join(cells))
    for c in result["comparison"]:
        lines.append(f"{c['task']} {c['target']}: cmrt / {c['best_peer']} = {c['ratio']:.2f} "
                     f"[{c['ratio_ci'][0]:.2f}, {c['ratio_ci'][1]:.2f}]")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", default="rise,push",
                   help="comma-separated task names (each at its default speed), or name:speed")
    p.add_argument("--optimizers", default=",".join(OPTIMIZERS))
    p.add_argument("--seeds", default="41-60")
    p.add_argument("--targets", default="", help="objective targets besides the first success, e.g. 0.9,0.8")
    p.add_argument("--max-evals", type=int, default=OptimizeSettings().max_evals)
    p.add_argument("--optuna-box", type=float, default=BOX,
                   help="optuna's search box, +- parameter units: its step size is a sixth of the box (its own "
                   "rule; 1.5 gives the project's 0.5)")
    p.add_argument("--json", action="store_true")
    p.add_argument("--quiet", action="store_true", help="no per-run lines on stderr")
    args = p.parse_args(argv)
    try:
        optimizers = args.optimizers.split(",")
        unknown = sorted(set(optimizers) - set(OPTIMIZERS))
        if unknown:
            raise CmrtError(f"--optimizers: unknown {', '.join(unknown)} (choose from {', '.join(OPTIMIZERS)})")
        try:
            seeds = parse_seeds(args.seeds)
            targets: list[float | str] = [SUCCESS] + [float(t) for t in args.targets.split(",") if t]
        except ValueError:
            raise CmrtError(f"--seeds like 41-60 or 1,3,5 and --targets like 0.9,0.8, not {args.seeds!r} and "
                            f"{args.targets!r}") from None
        if not seeds or args.max_evals < 1 or not args.optuna_box > 0:
            raise CmrtError("--seeds and --max-evals must name at least one seed and one evaluation, "
                            "--optuna-box a box > 0")
        tasks = []
        for spec in args.tasks.split(","):
            name, _, speed = spec.partition(":")
            tasks.append(resolve_task(name, float(speed) if speed else None))
        result = benchmark(tasks, optimizers, seeds, args.max_evals, targets, progress=not args.quiet,
                           optuna_box=args.optuna_box)
    except (CmrtError, ValueError) as exc:
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    print(json.dumps(result) if args.json else _text(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
