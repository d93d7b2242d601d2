"""The project's optimizer against what a user would pick instead, on the same evaluator, budget and verdict.

    python tools/peer_benchmark.py --tasks bend,catch,push,punch,rise --seeds 21-30 [--optimizers ...]
                                   [--max-evals 3000] [--json]

Optimizers (``--optimizers``, comma-separated; all by default):

* ``cmrt``: ``cmrt optimize TASK --init none --seed S`` (``optimize_now`` into a scratch store, the
  default settings: step size 0.5, population 10, BIPOP restarts, stopping rules);
* ``optuna``: optuna's ``CmaEsSampler`` (ask/tell, one generation of trials evaluated as one batch) over a
  box of +-``BOX`` parameter units centred on the flat CMRT, its step size in the normalised box set to the
  same parameter-space sigma as the project's (sigma / box width), the same population, no restarts;
* ``cmaes``: the ``cmaes`` library's ``CMA`` from the flat CMRT with the same sigma and population, restarted
  IPOP-style (population doubled) whenever its own ``should_stop()`` fires;
* ``random``: independent draws from N(0, sigma^2 I) around the flat CMRT (numpy Generator of the seed).

Every candidate is scored by the batched evaluator (``cmrt.Evaluator``) with the task's ``success`` flag;
each run goes on until a success below the task's ``stop_threshold`` (the project's threshold stop) or
the budget. Per (task, optimizer): ``success_rate`` (a success found), ``under_threshold_rate`` (a
success below the threshold found), median and worst evaluations to the first success and to the first
success below the threshold (over the seeds that found one), and wall time. Optuna and cmaes are test
extras (``pip install -e .[test]``), not runtime dependencies. The seeds the results pages' tables use are 1-10;
hold the optimizer's own tuning out of the seeds you report.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from cmrt import CmrtError, Evaluator, OptimizeSettings, Task, open_store, optimize_now, resolve_task
from cmrt.optimize.driver import N_PARAMS

OPTIMIZERS = ("cmrt", "optuna", "cmaes", "random")
BOX = 10.0  # optuna's search box, +- parameter units (+-0.5 m of CoM shift): wider than any shipped CMRT (<= 7.5)
RANDOM_BATCH = 10  # random draws per evaluator call (the project's population)


class Budget:
    """Counts a run's evaluations and remembers the first success and the first one below the threshold."""

    def __init__(self, task: Task, evaluator: Evaluator, max_evals: int):
        self.task, self.evaluator, self.max_evals = task, evaluator, max_evals
        self.evaluations = 0
        self.first_success: int | None = None
        self.first_under: int | None = None
        self.best_objective = float("inf")
        self.best_success = False

    @property
    def done(self) -> bool:
        return self.first_under is not None or self.evaluations >= self.max_evals

    def __call__(self, xs: list[np.ndarray]) -> list[float]:
        xs = xs[: self.max_evals - self.evaluations]
        records = self.evaluator(self.task, xs) if xs else []
        for r in records:
            self.note(r.objective, r.success)
        return [r.objective for r in records]

    def note(self, objective: float, success: bool) -> None:
        self.evaluations += 1
        if objective < self.best_objective:
            self.best_objective, self.best_success = objective, success
        if success and self.first_success is None:
            self.first_success = self.evaluations
        if success and objective < self.task.stop_threshold and self.first_under is None:
            self.first_under = self.evaluations


def run_cmrt(budget: Budget, seed: int, sigma: float, popsize: int) -> dict:
    """The project's own driver, exactly as ``cmrt optimize --init none`` runs it."""
    with tempfile.TemporaryDirectory() as tmp, open_store(Path(tmp) / "run.sqlite") as store:
        run = optimize_now(store, budget.task, budget.evaluator, seed=seed, init="none",
                           max_evals=budget.max_evals)
        for e in store.evaluations(run.id):
            budget.note(e.objective, e.success)
    return {"stop_reason": run.stop_reason, "restarts": run.restarts}


def run_optuna(budget: Budget, seed: int, sigma: float, popsize: int) -> dict:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.ERROR)
    sampler = optuna.samplers.CmaEsSampler(sigma0=sigma / (2 * BOX), seed=seed, popsize=popsize,
                                           x0={f"u{i}": 0.0 for i in range(N_PARAMS)})
    study = optuna.create_study(sampler=sampler, direction="minimize")
    dists = {f"u{i}": optuna.distributions.FloatDistribution(-BOX, BOX) for i in range(N_PARAMS)}
    while not budget.done:
        trials = [study.ask(dists) for _ in range(min(popsize, budget.max_evals - budget.evaluations))]
        xs = [np.array([t.params[f"u{i}"] for i in range(N_PARAMS)]) for t in trials]
        for t, f in zip(trials, budget(xs), strict=True):
            study.tell(t, f)
    return {}


def run_cmaes(budget: Budget, seed: int, sigma: float, popsize: int) -> dict:
    from cmaes import CMA

    rng = np.random.default_rng(seed)
    restarts = 0
    while not budget.done:
        opt = CMA(mean=np.zeros(N_PARAMS), sigma=sigma, population_size=popsize * 2**restarts,
                  seed=int(rng.integers(1, 2**31 - 1)))
        while not budget.done and not opt.should_stop():
            xs = [opt.ask() for _ in range(opt.population_size)]
            fs = budget(xs)
            if len(fs) < len(xs):
                break  # the budget ended inside the generation
            opt.tell(list(zip(xs, fs, strict=True)))
        restarts += 1
    return {"restarts": restarts - 1}


def run_random(budget: Budget, seed: int, sigma: float, popsize: int) -> dict:
    rng = np.random.default_rng(seed)
    while not budget.done:
        budget(list(sigma * rng.standard_normal((RANDOM_BATCH, N_PARAMS))))
    return {}


RUNNERS: dict[str, Callable[[Budget, int, float, int], dict]] = {
    "cmrt": run_cmrt, "optuna": run_optuna, "cmaes": run_cmaes, "random": run_random}


def benchmark(tasks: list[Task], optimizers: list[str], seeds: list[int], max_evals: int,
              progress: bool = False) -> dict:
    rows = []
    popsize, sigma = OptimizeSettings().popsize, OptimizeSettings().sigma0  # the project's, for every peer
    with Evaluator("batch") as ev:
        for task in tasks:
            for name in optimizers:
                runs = []
                for seed in seeds:
                    t0 = time.perf_counter()
                    budget = Budget(task, ev, max_evals)
                    extra = RUNNERS[name](budget, seed, sigma, popsize)
                    runs.append({"seed": seed, "evaluations": budget.evaluations,
                                 "first_success_evals": budget.first_success,
                                 "first_under_threshold_evals": budget.first_under,
                                 "best_objective": budget.best_objective, "best_success": budget.best_success,
                                 "wall_s": round(time.perf_counter() - t0, 2), **extra})
                    if progress:
                        print(json.dumps({"task": task.name, "optimizer": name, **runs[-1]}), file=sys.stderr)
                rows.append(summarize(task, name, sigma, runs))
    return {"max_evals": max_evals, "seeds": seeds, "popsize": popsize, "optuna_box": BOX, "rows": rows,
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"}


def _median(values: list[int]) -> float | None:
    return statistics.median(values) if values else None


def summarize(task: Task, optimizer: str, sigma: float, runs: list[dict]) -> dict:
    found = [r["first_success_evals"] for r in runs if r["first_success_evals"] is not None]
    under = [r["first_under_threshold_evals"] for r in runs if r["first_under_threshold_evals"] is not None]
    return {
        "task": task.name, "speed": task.speed, "optimizer": optimizer, "sigma0": sigma,
        "stop_threshold": task.stop_threshold,
        "success_rate": len(found) / len(runs), "under_threshold_rate": len(under) / len(runs),
        "median_evals_to_success": _median(found), "worst_evals_to_success": max(found) if found else None,
        "median_evals_to_under_threshold": _median(under),
        "worst_evals_to_under_threshold": max(under) if under else None,
        "wall_s": round(sum(r["wall_s"] for r in runs), 1), "runs": runs,
    }


def parse_seeds(text: str) -> list[int]:
    seeds: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        seeds.extend(range(int(lo), int(hi or lo) + 1))
    return seeds


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", default="bend,catch,push,punch,rise",
                   help="comma-separated task names (each at its default speed), or name:speed")
    p.add_argument("--optimizers", default=",".join(OPTIMIZERS))
    p.add_argument("--seeds", default="21-30")
    p.add_argument("--max-evals", type=int, default=OptimizeSettings().max_evals)
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
        except ValueError:
            raise CmrtError(f"--seeds: give seeds like 21-30 or 1,3,5, not {args.seeds!r}") from None
        if not seeds or args.max_evals < 1:
            raise CmrtError("--seeds and --max-evals must name at least one seed and one evaluation")
        tasks = []
        for spec in args.tasks.split(","):
            name, _, speed = spec.partition(":")
            tasks.append(resolve_task(name, float(speed) if speed else None))
        result = benchmark(tasks, optimizers, seeds, args.max_evals, progress=not args.quiet)
    except (CmrtError, ValueError) as exc:
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result))
        return 0
    n = len(seeds)
    print(f"{n} seeds ({args.seeds}), budget {args.max_evals} evaluations, population {result['popsize']}")
    print(f"{'task':10} {'optimizer':9} {'success':>8} {'<thresh':>8} {'median':>7} {'worst':>6} "
          f"{'median<':>8} {'worst<':>7} {'wall s':>7}")
    for r in result["rows"]:
        speed = f" {r['speed']:g}" if r["speed"] is not None else ""
        print(f"{r['task'] + speed:10} {r['optimizer']:9} {round(r['success_rate'] * n):>4}/{n:<3} "
              f"{round(r['under_threshold_rate'] * n):>4}/{n:<3} {r['median_evals_to_success'] or '-':>7} "
              f"{r['worst_evals_to_success'] or '-':>6} {r['median_evals_to_under_threshold'] or '-':>8} "
              f"{r['worst_evals_to_under_threshold'] or '-':>7} {r['wall_s']:>7}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
