"""How hard is a task? The fraction of random CMRTs from CMA-ES's start distribution that succeed.

    python tools/random_success.py bend --speed 0.4 [--set KEY=VALUE ...] [--samples 200] [--seed 1] [--json]

The candidates are drawn from exactly the distribution ``cmrt optimize TASK --init none`` starts from:
the mean, step size and covariance of the optimizer's own fresh CMA-ES (``cmrt.optimize.driver.new_state``:
x0 = 0, the flat CMRT, and ``sigma0``) in its 8-parameter space, mapped to CMRTs by the optimizer's
``Cmrt.from_params``. They are drawn from a numpy Generator of their own seeded by ``--seed`` (not the
global RNG, not pycma's), simulated with the batched evaluator (``simulate_batch``) and scored by
``evaluate`` (a 3D task's one by one, as ``cmrt simulate`` scores it). A task where most such draws
already succeed is easy for any search; one where none do is where the optimizer's restarts and budget
matter. Reports the success fraction with its 95 % Wilson
interval, the fraction of successes below the task's ``stop_threshold`` (a first generation drawing one
stops the run), the fractions that fell and that stood without performing the motion (or reaching the
goal), the objective's median and minimum, the seed, wall time and the machine.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from dataclasses import dataclass

import numpy as np

from cmrt import Cmrt, CmrtError, OptimizeSettings, Task, evaluate, resolve_task, simulate_report
from cmrt.inputs import SEED, SPEED, Range, parse_sets
from cmrt.optimize.driver import new_state
from cmrt.sim.simulate import simulate_batch

SAMPLES = Range(1, 100_000, integer=True)
CHUNK = 64  # clips per simulate_batch call: bounds the per-step records' memory (a clip's score does not
# depend on its batch)
WILSON_Z = 1.959964  # the normal quantile of a two-sided 95 % interval


@dataclass(frozen=True)
class StartDistribution:
    """CMA-ES's first-generation sampling distribution: mean + sigma * scaling * (chol(C) z), z ~ N(0, I)."""

    mean: np.ndarray
    sigma: float
    scaling: np.ndarray  # pycma's per-coordinate sigma_vec
    cov_chol: np.ndarray

    @classmethod
    def cold(cls, n_params: int = 8) -> StartDistribution:
        """The distribution of ``cmrt optimize --init none``, read off the optimizer's own fresh CMA-ES (so
        a change of x0, sigma0 or pycma's initial covariance - not exactly I - is followed here); ``n_params``:
        the task's CMRT's (12 in two axes)."""
        es = new_state(OptimizeSettings(n_params=n_params)).es
        return cls(mean=np.array(es.mean, dtype=float), sigma=float(es.sigma),
                   scaling=np.broadcast_to(np.asarray(es.sigma_vec.scaling, dtype=float), es.mean.shape).copy(),
                   cov_chol=np.linalg.cholesky(np.asarray(es.sm.C, dtype=float)))

    def draw(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """(n, 8) parameter vectors ((n, 12) in two axes)."""
        z = rng.standard_normal((n, self.mean.size))
        return self.mean + self.sigma * self.scaling * (z @ self.cov_chol.T)


def wilson_interval(successes: int, n: int, z: float = WILSON_Z) -> tuple[float, float]:
    """The Wilson score interval of a binomial fraction (sensible at 0 and n successes, unlike p +- z se)."""
    p = successes / n
    denom = 1.0 + z * z / n
    center = (p + z * z / (2 * n)) / denom
    half = z / denom * math.sqrt(p * (1.0 - p) / n + z * z / (4 * n * n))
    return max(0.0, center - half), min(1.0, center + half)


@dataclass(frozen=True)
class Score:
    """What the table counts of one clip."""

    objective: float
    success: bool
    fell: bool
    performed: bool | None
    settled: bool


def _scores(task: Task, curves: list[Cmrt]) -> list[Score]:
    """The clips of ``curves`` scored: a planar task's in one batch, a 3D task's one by one (its report)."""
    if task.body == "planar":
        return [Score(e.objective, e.success, e.fell, e.performed, e.settled)
                for e in (evaluate(task, tr) for tr in simulate_batch(task, curves))]
    out = []
    for curve in curves:
        r = simulate_report(task, curve, "random")
        failed = set(r["failed_rules"])
        out.append(Score(r["objective"], r["success"], r["fell"], not failed & {"performed", "on_time"},
                         "settled" not in failed))
    return out


def measure(task: Task, samples: int, seed: int) -> dict:
    """Score ``samples`` random CMRTs of ``task`` drawn with generator seed ``seed``."""
    t0 = time.perf_counter()
    dist = StartDistribution.cold(task.n_cmrt_params)
    xs = dist.draw(np.random.default_rng(seed), samples)
    scores = []
    for a in range(0, samples, CHUNK):
        curves = [Cmrt.from_params(x, task.clip_s) for x in xs[a : a + CHUNK]]
        scores += _scores(task, curves)
    wins = sum(e.success for e in scores)
    fell = sum(e.fell for e in scores)
    not_performed = sum(e.performed is False and not e.fell for e in scores)
    objectives = np.array([e.objective for e in scores])
    lo, hi = wilson_interval(wins, samples)
    return {
        "task": task.name, "speed": task.speed, "samples": samples, "seed": seed,
        "successes": wins, "success_fraction": wins / samples,
        # successes the optimizer would stop at (its threshold rule) if its first generation drew them
        "under_threshold_fraction": sum(e.success and e.objective < task.stop_threshold for e in scores) / samples,
        "stop_threshold": task.stop_threshold,
        "success_fraction_wilson95": [lo, hi],
        "fell_fraction": fell / samples,
        "not_performed_fraction": not_performed / samples,  # stood, but the motion or goal was not done
        "not_settled_fraction": sum(not e.fell and e.performed is not False and not e.settled for e in scores)
        / samples,
        "objective_median": float(np.median(objectives)), "objective_min": float(objectives.min()),
        "start": {"x0": dist.mean.tolist(), "sigma0": dist.sigma},
        "wall_s": round(time.perf_counter() - t0, 1),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("task")
    p.add_argument("--speed")
    p.add_argument("--set", action="append", metavar="KEY=VALUE")
    p.add_argument("--samples", default="200")
    p.add_argument("--seed", default="1")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    try:
        samples = int(SAMPLES.check(args.samples, "--samples"))
        seed = int(SEED.check(args.seed, "--seed"))
        speed = None if args.speed is None else float(SPEED.check(args.speed, "--speed"))
        task = resolve_task(args.task, speed, parse_sets(args.set))
        result = measure(task, samples, seed)
    except (CmrtError, ValueError) as exc:
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result))
    else:
        speed = f" --speed {task.speed:g}" if task.speed is not None else ""
        lo, hi = result["success_fraction_wilson95"]
        print(f"{task.name}{speed}: {result['successes']}/{samples} random CMRTs succeed "
              f"({result['success_fraction']:.1%}, 95 % {lo:.1%}-{hi:.1%}; below the threshold "
              f"{task.stop_threshold:g}: {result['under_threshold_fraction']:.1%}); "
              f"fell {result['fell_fraction']:.1%}, "
              f"not performed {result['not_performed_fraction']:.1%}; objective median "
              f"{result['objective_median']:.3f}, min {result['objective_min']:.3f}; seed {seed}, "
              f"{result['wall_s']} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
