"""ABC 4.2 check: interpolated CMRTs vs CMRTs optimized directly at the same speed.

Interpolates the library's bend family (0.4, 0.6, 0.8, 1.0, 1.2 s) at 0.5, 0.7, 0.9 and
1.1 s, optimizes each of those speeds from scratch with the same budget and seed as the
family (into a scratch store), and extrapolates to 0.35 and 1.3 s. ``--task`` another task with
a library family (the 3D leg lift's clips scored as ``cmrt simulate`` scores them).

    python tools/interpolation_table.py [--max-evals 1500] [--json]
    python tools/interpolation_table.py --task leg-lift --between 2.05,2.55,3.05 --beyond 1.6,3.5 --max-evals 300
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from cmrt import Cmrt, Evaluator, evaluate, interpolate, load_task, open_store, optimize_now, simulate, simulate_report


def score(task, curve) -> tuple[float, bool]:
    """A clip's objective and success (a planar one unrecorded; a 3D one as ``cmrt simulate`` scores it)."""
    if task.body != "planar":
        r = simulate_report(task, curve, "interpolated")
        return r["objective"], r["success"]
    e = evaluate(task, simulate(task, curve, record=False))
    return e.objective, e.success


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", default="bend")
    ap.add_argument("--between", default="0.5,0.7,0.9,1.1")
    ap.add_argument("--beyond", default="0.35,1.3")
    ap.add_argument("--max-evals", type=int, default=1500)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp, open_store(Path(tmp) / "direct.sqlite") as store:
        for kind, speeds in (("interpolated", args.between), ("extrapolated", args.beyond)):
            for speed in [float(v) for v in speeds.split(",") if v.strip()]:
                task = load_task(args.task).with_speed(speed).with_params(stop_threshold=0.0)
                r = interpolate(task)
                interp, zero = score(task, r.curve), score(task, Cmrt.zero(task.clip_s))
                row = {"speed": speed, "kind": kind, "zero_objective": zero[0], "zero_success": zero[1],
                       "interpolated_objective": interp[0], "interpolated_success": interp[1],
                       "from": [v for v, _ in r.sources], "weight": r.weight}
                if kind == "interpolated":
                    with Evaluator("batch") as ev:
                        run = optimize_now(store, task, ev, seed=1, max_evals=args.max_evals, init="none")
                    row.update(direct_objective=run.best_objective, direct_success=run.best_success,
                               ratio=interp[0] / run.best_objective)
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
