"""ABC 4.2 check: interpolated CMRTs vs CMRTs optimized directly at the same speed.

Interpolates the library's bend family (0.4, 0.6, 0.8, 1.0, 1.2 s) at 0.5, 0.7, 0.9 and
1.1 s, optimizes each of those speeds from scratch with the same budget and seed as the
family (into a scratch store), and extrapolates to 0.35 and 1.3 s.

    python tools/interpolation_table.py [--max-evals 1500] [--json]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from cmrt import Evaluator, evaluate, interpolate, load_task, open_store, optimize_now, simulate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--between", default="0.5,0.7,0.9,1.1")
    ap.add_argument("--beyond", default="0.35,1.3")
    ap.add_argument("--max-evals", type=int, default=1500)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp, open_store(Path(tmp) / "direct.sqlite") as store:
        for kind, speeds in (("interpolated", args.between), ("extrapolated", args.beyond)):
            for speed in map(float, speeds.split(",")):
                task = load_task("bend").with_speed(speed).with_params(stop_threshold=0.0)
                r = interpolate(task)
                interp = evaluate(task, simulate(task, r.curve, record=False))
                zero = evaluate(task, simulate(task, record=False))
                row = {"speed": speed, "kind": kind, "zero_objective": zero.objective, "zero_success": zero.success,
                       "interpolated_objective": interp.objective, "interpolated_success": interp.success,
                       "from": [v for v, _ in r.sources], "weight": r.weight}
                if kind == "interpolated":
                    with Evaluator("batch") as ev:
                        run = optimize_now(store, task, ev, seed=1, max_evals=args.max_evals, init="none")
                    row.update(direct_objective=run.best_objective, direct_success=run.best_success,
                               ratio=interp.objective / run.best_objective)
                rows.append(row)
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    print("| T (s) | from | zero CMRT | interpolated | optimized directly | interpolated / direct |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        fail = lambda ok: "" if ok else " (not a success)"  # noqa: E731
        direct = (f"{r['direct_objective']:.3f}{fail(r['direct_success'])} | {r['ratio']:.2f}"
                  if "direct_objective" in r else "- | -")
        src = " & ".join(f"{v:g}" for v in r["from"]) + (" (extrapolated)" if r["kind"] == "extrapolated" else "")
        print(f"| {r['speed']:g} | {src} | {r['zero_objective']:.3f}{fail(r['zero_success'])} | "
              f"{r['interpolated_objective']:.3f}{fail(r['interpolated_success'])} | {direct} |")


if __name__ == "__main__":
    main()
