"""Re-measure every shipped library CMRT on the current physics, without re-optimizing it.

When the physics changes (a contact, a limit), an entry's figures - its objective and verdict, its zero CMRT's,
its validation ensemble - no longer hold. This replays each entry's own CMRT as it is (its knots stay the ones the
optimizer found, with their provenance: seed, evaluations, start) the way ``tools/find_library_curve.py`` scores a
new one, rewrites those figures and says when in ``rescored``. A CMRT that is no longer a success is reported (exit
code 1) so that it is re-optimized rather than shipped:

    python tools/rescore_library.py                # rewrite cmrt/motion/library.json
    python tools/rescore_library.py --dry-run --json   # what would change
    python tools/rescore_library.py --only bend --dry-run
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
from pathlib import Path

from cmrt import evaluate, simulate
from cmrt.motion.curve import Cmrt
from cmrt.motion.library import LIBRARY_PATH, load_entries
from cmrt.motion.taskfile import resolve_task
from cmrt.sim.validate import robustness

CLIP_FIGURES = ("objective", "success", "fell", "task_success", "tracking_error_rad", "min_cop_margin_m",
                "final_pose_error_rad")  # an entry's own clip, as find_library_curve.py records it
ZERO_FIGURES = ("objective", "success", "fell")  # its zero CMRT's, as zero_cmrt_<figure>


def entry_task(entry: dict):
    """The task an entry was optimized for: its task file with the entry's parameters, reference mode, footstep
    plan and ensemble."""
    task = resolve_task(entry["task"], params=entry.get("params") or None, reference=entry.get("reference"),
                        steps=entry.get("steps") or None)
    if entry.get("speed") is not None and entry.get("params") is None:
        task = task.with_speed(entry["speed"])
    return task.with_robust() if entry.get("robust") else task


def rescore(entry: dict, when: str) -> dict:
    """The entry with its figures measured again on this physics (its CMRT, parameters and provenance kept)."""
    task = entry_task(entry)
    curve = Cmrt.from_dict(entry["cmrt"])
    check = evaluate(task, simulate(task, curve))
    zero = evaluate(task, simulate(task, Cmrt.zero(task.clip_s), record=False))
    out = dict(entry)
    out.update({k: getattr(check, k) for k in CLIP_FIGURES})
    out.update({f"zero_cmrt_{k}": getattr(zero, k) for k in ZERO_FIGURES})
    if entry.get("robustness") is not None:
        out["robustness"] = robustness(task, curve)
    out["rescored"] = when
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--library", type=Path, default=LIBRARY_PATH)
    ap.add_argument("--only", help="rescore this task's entries alone")
    ap.add_argument("--when", default="", help="what to record in each entry's 'rescored' (a date, a physics "
                                                 "version); default: today's date")
    ap.add_argument("--dry-run", action="store_true", help="measure and report, write nothing")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if not args.library.exists():
        print(f"rescore_library: no library at {args.library}", file=sys.stderr)
        return 2
    when = args.when or datetime.date.today().isoformat()
    entries = load_entries(args.library)
    rows, out = [], []
    for entry in entries:
        if args.only and entry["task"] != args.only:
            out.append(entry)
            continue
        new = rescore(entry, when)
        out.append(new)
        rows.append({"task": entry["task"], "speed": entry.get("speed"), "reference": entry.get("reference", "center"),
                     "robust": bool(entry.get("robust")), "steps": entry.get("steps", ""),
                     **{f"old_{k}": entry.get(k) for k in ("objective", "success")},
                     **{k: new[k] for k in ("objective", "success", "zero_cmrt_objective", "zero_cmrt_success")}})
    lost = [r for r in rows if r["old_success"] and not r["success"]]
    if args.json:
        print(json.dumps({"rows": rows, "lost": len(lost)}, indent=2))
    else:
        print("| task | speed | reference | robust | objective: was -> now | success: was -> now | zero CMRT |")
        print("|---|---|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['task']} | {r['speed']} | {r['reference']} | {'yes' if r['robust'] else 'no'} | "
                  f"{r['old_objective']:.4f} -> {r['objective']:.4f} | {r['old_success']} -> {r['success']} | "
                  f"{r['zero_cmrt_objective']:.3f} ({'success' if r['zero_cmrt_success'] else 'no'}) |")
    if not args.dry_run:
        args.library.write_text(json.dumps({"entries": out}, indent=2) + "\n")
        print(f"wrote {args.library}", file=sys.stderr)
    return 1 if lost else 0


if __name__ == "__main__":
    sys.exit(main())
