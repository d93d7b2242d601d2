"""Evaluations per second: serial vs loky (2 workers) [vs dask LocalCluster], one run.

The candidate set mixes what CMA-ES evaluates: samples around the flat start (many fall
early, cheap) and around the library optimum (full clips). Worker start-up is excluded
(one warm-up generation per backend), as it is paid once per run.

    python tools/bench_backends.py [--candidates 40] [--workers 2] [--dask] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from cmrt import Evaluator, library_curve, load_task


def main() -> None:
    ap = argparse.ArgumentParser(description="evaluations/s per backend")
    ap.add_argument("--candidates", type=int, default=40)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--dask", action="store_true", help="also measure a dask LocalCluster")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds; best round per backend")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    task = load_task("bend").with_speed(0.4)
    rng = np.random.default_rng(0)
    best = library_curve(task).to_params()
    half = args.candidates // 2
    xs = [rng.normal(0, 0.5, 8) for _ in range(half)] + [best + rng.normal(0, 0.1, 8) for _ in range(half)]

    results = {"candidates": len(xs), "workers": args.workers, "cpus": os.cpu_count(), "rounds": args.rounds}
    backends = ["serial", "loky"] + (["dask"] if args.dask else [])
    evaluators = {b: Evaluator(b, workers=args.workers) for b in backends}
    reference = None
    try:
        for ev in evaluators.values():
            ev(task, xs[:4])  # warm-up: worker start, model compile, settled state
        for _ in range(args.rounds):  # alternate so machine noise hits every backend alike
            for backend, ev in evaluators.items():
                t0 = time.perf_counter()
                objectives = [r.objective for r in ev(task, xs)]
                rate = len(xs) / (time.perf_counter() - t0)
                reference = reference or objectives
                key = f"{backend}_evals_per_s"
                results[key] = max(results.get(key, 0.0), rate)
                results[f"{backend}_identical_to_serial"] = objectives == reference
    finally:
        for ev in evaluators.values():
            ev.close()
    results["loky_speedup"] = results["loky_evals_per_s"] / results["serial_evals_per_s"]
    if args.json:
        print(json.dumps(results, indent=2))
    else:
        for k, v in results.items():
            print(f"{k:28s} {v:.3f}" if isinstance(v, float) else f"{k:28s} {v}")


if __name__ == "__main__":
    main()
