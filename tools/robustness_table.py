"""Zero vs plain vs robust CMRT on the validation ensemble, for every library entry (docs/results/reliability.md).

    python tools/robustness_table.py [--json] [--task TASK]

For each shipped (task, speed, parameters): the nominal clip's success and objective, and
``cmrt.sim.validate.robustness`` (20 seeded perturbed clips: +-25 N x 0.1 s thorax pushes at
random moments, prop mass +-10 %, timing +-5 %) for the zero CMRT, the plain library CMRT
and the robust library CMRT.
"""

from __future__ import annotations

import argparse
import json
import sys

from cmrt import Cmrt, CmrtError, evaluate, library_curve, load_task, robustness, simulate
from cmrt.motion.library import load_entries


def rows(only: str | None) -> list[dict]:
    out = []
    seen = set()
    for entry in load_entries():
        params = {k: v for k, v in entry["params"].items() if k != "stop_threshold"}
        key = (entry["task"], json.dumps(params, sort_keys=True))
        if key in seen or (only and entry["task"] != only):
            continue
        seen.add(key)
        task = load_task(entry["task"]).with_params(**params)
        curves = {"zero": Cmrt.zero(task.clip_s)}
        for kind, robust in (("plain", False), ("robust", True)):
            try:
                curves[kind] = library_curve(task, robust=robust)
            except CmrtError:
                pass
        for kind, curve in curves.items():
            nominal = evaluate(task, simulate(task, curve, record=False))
            out.append({"task": task.name, "speed": task.speed, "params": params, "curve": kind,
                        "success": nominal.success, "objective": nominal.objective,
                        **robustness(task, curve)})
            print(json.dumps(out[-1]), file=sys.stderr)
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", action="store_true")
    p.add_argument("--task")
    args = p.parse_args()
    table = rows(args.task)
    if args.json:
        print(json.dumps(table))
        return 0
    print("| task | curve | nominal success | objective | validation succeed | fall | min CoP margin |")
    print("|---|---|---|---|---|---|---|")
    for r in table:
        label = f"{r['task']} {r['speed']:g}" if r["speed"] is not None else r["task"]
        if r["task"] == "catch":
            label += f" ({r['params']['ball_mass_kg']:g} kg)"
        margin = "-" if r["min_cop_margin_m"] is None else f"{100 * r['min_cop_margin_m']:.1f} cm"
        print(f"| {label} | {r['curve']} | {'yes' if r['success'] else 'no'} | {r['objective']:.3f} | "
              f"{r['validation_survived']}/{r['validation_total']} | {r['validation_fell']} | {margin} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
