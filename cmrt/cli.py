"""The ``cmrt`` command: a thin layer over the Python API.

Bad input (unknown task, bad value, unreadable file) prints one line,
``cmrt: error: ...``, and exits with status 2 - never a traceback.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cmrt.character import character
from cmrt.curve import Cmrt
from cmrt.errors import CmrtError
from cmrt.library import library_curve
from cmrt.objective import evaluate
from cmrt.simulate import simulate
from cmrt.task import Task, available_tasks, load_task

EXIT_BAD_INPUT = 2


class _Parser(argparse.ArgumentParser):
    """argparse, but usage errors are one line and exit 2 like every other bad input."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise CmrtError(message)


def _parse_sets(items: list[str] | None) -> dict[str, str]:
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise CmrtError(f"--set expects KEY=VALUE, got '{item}'")
        out[key.strip()] = value.strip()
    return out


def resolve_task(name: str, speed: float | None, sets: list[str] | None) -> Task:
    task = load_task(name)
    overrides = _parse_sets(sets)
    if overrides:
        task = task.with_params(**overrides)
    return task.with_speed(speed)


def resolve_curve(spec: str, task: Task) -> tuple[Cmrt, str]:
    """zero | library | FILE.json -> (curve, description)."""
    if spec == "zero":
        return Cmrt.zero(task.clip_s), "zero"
    if spec == "library":
        return library_curve(task), "library"
    path = Path(spec)
    if path.suffix.lower() == ".json" or path.exists():
        curve = Cmrt.load(path)
        if abs(curve.clip_s - task.clip_s) > 1e-9:
            raise CmrtError(f"CMRT in {spec} is for a {curve.clip_s:g} s clip, task clip is {task.clip_s:g} s")
        return curve, str(path)
    raise CmrtError(f"--curve must be zero, library or a CMRT .json file, got '{spec}'")


def _finite(x):
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else x


def simulate_report(task: Task, curve: Cmrt, curve_name: str, trace: str | None = None) -> dict:
    t0 = time.perf_counter()
    traj = simulate(task, curve)
    ev = evaluate(task, traj)
    wall = time.perf_counter() - t0
    if trace:
        _save_npz(trace, {**traj.as_npz_dict(), "dof_names": np.array(character().dof_names)})
    return {
        "task": task.name,
        "speed": task.speed,
        "params": task.params,
        "curve": curve_name,
        "cmrt": curve.to_dict(),
        "objective": _finite(ev.objective),
        "cop_error_norm": _finite(ev.cop_error_norm),
        "penalty": ev.penalty,
        "fell": ev.fell,
        "fall_time_s": ev.fall_time_s,
        "fall_reason": ev.fall_reason,
        "diverged": ev.diverged,
        "max_cop_error_m": _finite(ev.max_cop_error_m),
        "final_pose_error_rad": _finite(ev.final_pose_error_rad),
        "n_samples": ev.n_samples,
        "wall_s": round(wall, 4),
    }


def _save_npz(path: str, arrays: dict) -> None:
    """Write atomically: a failed write never leaves a half-written file."""
    target = Path(path)
    if not target.parent.exists():
        raise CmrtError(f"cannot write trace: directory {target.parent} does not exist")
    fd, tmp = tempfile.mkstemp(dir=target.parent, suffix=".npz.tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez_compressed(fh, **arrays)
        os.replace(tmp, target)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise CmrtError(f"cannot write trace {path}: {exc.strerror}") from None


def _print_report(r: dict) -> None:
    speed = f" --speed {r['speed']:g}" if r["speed"] is not None else ""
    status = f"LOST BALANCE at {r['fall_time_s']:.3f} s ({r['fall_reason']})" if r["fell"] else "balance kept"
    print(f"{r['task']}{speed}  curve={r['curve']}: {status}")
    print(
        f"  objective {r['objective']:.4f}  (CoP-error 2-norm {r['cop_error_norm']:.4f} m + penalty {r['penalty']:.2f})"
    )
    print(
        f"  max |CoP error| {r['max_cop_error_m']:.4f} m  final pose error {r['final_pose_error_rad']:.4f} rad  "
        f"[{r['wall_s']:.2f} s]"
    )


def cmd_tasks(args) -> int:
    rows = []
    for name in available_tasks():
        t = load_task(name)
        rows.append(
            {
                "name": name,
                "summary": t.summary,
                "speed_param": t.speed_param,
                "speed": t.speed,
                "params": t.params,
                "param_ranges": {k: list(v) for k, v in t.param_ranges.items()},
            }
        )
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        for r in rows:
            sp = f" (speed: {r['speed_param']} = {r['speed']:g})" if r["speed_param"] else ""
            print(f"{r['name']:<10} {r['summary']}{sp}")
    return 0


def cmd_simulate(args) -> int:
    task = resolve_task(args.task, args.speed, args.set)
    curve, name = resolve_curve(args.curve, task)
    report = simulate_report(task, curve, name, args.trace)
    if args.json:
        print(json.dumps(report))
    else:
        _print_report(report)
    return 0


def cmd_demo(args) -> int:
    task = load_task("bend").with_speed(0.4)
    print("Fast bend (T = 0.4 s): the reactive controller alone, then with the library CMRT.")
    for spec in ("zero", "library"):
        curve, name = resolve_curve(spec, task)
        _print_report(simulate_report(task, curve, name))
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="cmrt", description="Anticipatory balance: center-of-mass reference trajectories.")
    sub = p.add_subparsers(dest="verb", required=True, parser_class=_Parser)

    s = sub.add_parser("tasks", help="list the task files")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_tasks)

    s = sub.add_parser("simulate", help="simulate one clip of a task with a CMRT")
    s.add_argument("task", help="task name (tasks/NAME.toml) or path to a .toml file")
    s.add_argument("--speed", type=float, help="the task's speed parameter (bend: duration T in s)")
    s.add_argument("--curve", default="zero", help="zero | library | FILE.json (default zero)")
    s.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a task parameter")
    s.add_argument("--json", action="store_true", help="print one JSON object")
    s.add_argument("--trace", metavar="FILE.npz", help="save the trajectories")
    s.set_defaults(func=cmd_simulate)

    s = sub.add_parser("demo", help="the fast bend with and without anticipation")
    s.set_defaults(func=cmd_demo)
    return p


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
        return args.func(args)
    except CmrtError as exc:
        print(f"cmrt: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("cmrt: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
