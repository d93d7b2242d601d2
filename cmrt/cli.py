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

from cmrt import jobs, query
from cmrt.curve import Cmrt
from cmrt.errors import CmrtError
from cmrt.library import library_curve
from cmrt.objective import evaluate
from cmrt.parallel import BACKENDS, Evaluator
from cmrt.simulate import simulate
from cmrt.store import DEFAULT_STORE, open_store, resolve_path
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


def resolve_curve(spec: str, task: Task, store_path: str | None = None) -> tuple[Cmrt, str]:
    """zero | library | RUN (a stored run id) | FILE.json -> (curve, description)."""
    if spec == "zero":
        return Cmrt.zero(task.clip_s), "zero"
    if spec in ("library", "library-robust"):
        return library_curve(task, robust=spec == "library-robust"), spec
    if spec.isdigit():
        with _store(store_path, create=False) as store:
            curve = query.run_curve(store, int(spec))
        if abs(curve.clip_s - task.clip_s) > 1e-9:
            raise CmrtError(f"run {spec} is for a {curve.clip_s:g} s clip, task clip is {task.clip_s:g} s")
        return curve, f"run {spec}"
    path = Path(spec)
    if path.suffix.lower() == ".json" or path.exists():
        curve = Cmrt.load(path)
        if abs(curve.clip_s - task.clip_s) > 1e-9:
            raise CmrtError(f"CMRT in {spec} is for a {curve.clip_s:g} s clip, task clip is {task.clip_s:g} s")
        return curve, str(path)
    raise CmrtError(f"--curve must be zero, library, a run id or a CMRT .json file, got '{spec}'")


def _store(path: str | None, create: bool = True):
    p = resolve_path(path)
    if create and p == DEFAULT_STORE and not p.parent.exists():
        p.parent.mkdir(parents=True)
    return open_store(p, create=create)


def _emit(obj, as_json: bool, text=None) -> None:
    """JSON (one line for objects, indented for lists) or the human form: a string, or a printer of obj."""
    if as_json:
        print(json.dumps(obj, indent=None if isinstance(obj, dict) else 2))
    elif callable(text):
        text(obj)
    else:
        print(text)


def _finite(x):
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else x


def simulate_report(task: Task, curve: Cmrt, curve_name: str, trace: str | None = None) -> dict:
    t0 = time.perf_counter()
    traj = simulate(task, curve)
    ev = evaluate(task, traj)
    wall = time.perf_counter() - t0
    if trace:
        _save_npz(trace, {**traj.as_npz_dict(), "dof_names": _dof_names(task)})
    return {
        "task": task.name,
        "speed": task.speed,
        "params": task.params,
        "curve": curve_name,
        "cmrt": curve.to_dict(),
        **evaluation_dict(ev),
        "wall_s": round(wall, 4),
    }


def evaluation_dict(ev) -> dict:
    """An Evaluation as JSON-safe values (non-finite floats become null)."""
    return {k: _finite(v) for k, v in ev.__dict__.items()}


def _dof_names(task: Task) -> np.ndarray:
    """Names of the trace's qvel columns: the humanoid's dofs, then the prop's."""
    m = task.model()
    return np.array([m.joint(int(m.dof_jntid[i])).name for i in range(m.nv)])


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


def _outcome(r: dict) -> str:
    if r["fell"]:
        return f"LOST BALANCE at {r['fall_time_s']:.3f} s ({r['fall_reason']})"
    if r["success"]:
        return "SUCCESS (balance kept, motion performed, standing still)"
    why = []
    if r["performed"] is False:
        why.append("motion not performed" if r["task_success"] is None else "goal missed")
    if not r["settled"]:
        why.append("not standing still after the clip")
    return "balance kept, but " + " and ".join(why)


def _print_report(r: dict) -> None:
    speed = f" --speed {r['speed']:g}" if r["speed"] is not None else ""
    print(f"{r['task']}{speed}  curve={r['curve']}: {_outcome(r)}")
    print(f"  objective {r['objective']:.4f}  (CoP-error 2-norm {r['cop_error_norm']:.4f} m "
          f"+ penalty {r['penalty']:.2f})")
    track = "-" if r["tracking_error_rad"] is None else f"{r['tracking_error_rad']:.3f}"
    if r["tracking_bound_rad"] is not None:
        track += f" (bound {r['tracking_bound_rad']:.3f})"
    print(f"  min CoP margin {100 * r['min_cop_margin_m']:.1f} cm  tracking error {track} rad  final pose error "
          f"{r['final_pose_error_rad']:.3f} rad  [{r['wall_s']:.2f} s]")
    print(f"  peak ground force {r['peak_normal_force_bw']:.2f} x body weight  airborne {r['airborne_s']:.3f} s  "
          f"max joint speed {r['max_joint_speed_rad_s']:.1f} rad/s")


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
    curve, name = resolve_curve(args.curve, task, args.store)
    _emit(simulate_report(task, curve, name, args.trace), args.json, _print_report)
    return 0


def cmd_demo(args) -> int:
    """The main job end to end: optimize the fast bend into the store, print the stored result."""
    task = load_task("bend").with_speed(0.4)
    print("Fast bend (T = 0.4 s, trunk first, both feet planted). The reactive controller alone:")
    _print_report(simulate_report(task, Cmrt.zero(task.clip_s), "zero"))
    store_path = resolve_path(args.store)
    print(f"\nOptimizing its CMRT with CMA-ES (seed 1) into {store_path} ...", flush=True)
    evaluator = Evaluator(args.backend, args.workers)
    try:
        with _store(args.store) as store:
            progress = _Progress(3000, enabled=sys.stderr.isatty())
            try:
                run = jobs.optimize_now(store, task, evaluator, progress, seed=1, init="none")
            finally:
                progress.close()
            stored = query.best_run(store, task)
            curve = query.run_curve(store, run["id"])
    finally:
        evaluator.close()
    print(f"\nStored in {store_path}; the best run for this task ('cmrt best bend --speed 0.4'):")
    _print_result(_result(stored))
    print(f"\nReplaying run {run['id']}'s CMRT ('cmrt simulate bend --speed 0.4 --curve {run['id']}'):")
    _print_report(simulate_report(task, curve, f"run {run['id']}"))
    print("\nThe library CMRT shipped with cmrt (a longer run; 'cmrt simulate bend --speed 0.4 --curve library'):")
    _print_report(simulate_report(task, library_curve(task), "library"))
    return 0


# --- optimization service -------------------------------------------------------
def _submit_kwargs(args) -> dict:
    return dict(
        seed=args.seed,
        max_evals=args.max_evals,
        popsize=args.popsize,
        sigma0=args.sigma0,
        min_evals=args.min_evals,
        init=args.init,
        stall_generations=args.stall_generations,
    )


def _opt_task(args, speed: float | None):
    """The task an optimization runs: with ``--robust``, scored on its ensemble."""
    task = resolve_task(args.task, speed, args.set)
    return task.with_robust() if args.robust else task


def cmd_submit(args) -> int:
    task = _opt_task(args, args.speed)
    with _store(args.store) as store:
        run_id = jobs.submit(store, task, **_submit_kwargs(args))
    _emit(
        {"run_id": run_id, "task": task.name, "speed": task.speed, "status": "queued"},
        args.json,
        f"queued run {run_id}: {task.name}" + (f" --speed {task.speed:g}" if task.speed is not None else ""),
    )
    return 0


class _Progress:
    """tqdm bar on stderr: generation, evaluations, best objective, sigma, evaluations/s."""

    def __init__(self, total: int, enabled: bool):
        from tqdm import tqdm

        self.bar = tqdm(total=total, unit="eval", file=sys.stderr, disable=not enabled, dynamic_ncols=True)

    def __call__(self, state, records, wall_s) -> None:
        self.bar.n = min(state.evaluations, self.bar.total)
        self.bar.set_postfix_str(
            f"gen {state.generation} best {state.best_objective:.4f} sigma {state.es.sigma:.3f} "
            f"{state.evaluations / max(wall_s, 1e-9):.1f} eval/s",
            refresh=True,
        )

    def close(self) -> None:
        self.bar.close()


def _result(run: dict) -> dict:
    return {
        "run_id": run["id"],
        "task": run["task"],
        "speed": run["speed"],
        "status": run["status"],
        "best_objective": run["best_objective"],
        "success": run["best_success"],
        "fell": run["best_fell"],
        "baseline_objective": run["baseline_objective"],
        "baseline_success": run["baseline_success"],
        "baseline_fell": run["baseline_fell"],
        "evaluations": run["evaluations"],
        "generations": run["generations"],
        "stop_reason": run["stop_reason"],
        "restarts": run.get("restarts") or 0,
        "init": run.get("init_source") or "none",
        "robust": run.get("robust") is not None,
        "robustness": run.get("robustness"),
        "wall_s": run["wall_s"],
        "best_cmrt": run["best_cmrt"],
    }


def _print_result(r: dict) -> None:
    speed = f" --speed {r['speed']:g}" if r["speed"] is not None else ""
    def outcome(success, fell):
        return "SUCCESS" if success else ("balance LOST" if fell else "not a success (balance kept)")

    print(
        f"run {r['run_id']} {r['task']}{speed}: {r['status']} ({r['stop_reason']}) after {r['evaluations']} "
        f"evaluations, {r['restarts']} restarts, {r['wall_s']:.1f} s; start: {r['init']}"
    )
    base = outcome(r["baseline_success"], r["baseline_fell"])
    print(f"  zero CMRT:      objective {r['baseline_objective']:.4f}  {base}")
    kind = "robust CMRT:   " if r["robust"] else "optimized CMRT:"
    print(f"  {kind} objective {r['best_objective']:.4f}  {outcome(r['success'], r['fell'])}")
    rb = r.get("robustness")
    if rb:
        margin = "n/a" if rb["min_cop_margin_m"] is None else f"{rb['min_cop_margin_m'] * 100:.1f} cm"
        print(f"  validation:     {rb['validation_survived']}/{rb['validation_total']} perturbed clips succeed, "
              f"{rb['validation_fell']} fall; min CoP margin {margin}")


def cmd_optimize(args) -> int:
    if args.speeds:
        return _optimize_family(args)
    task = _opt_task(args, args.speed)
    evaluator = Evaluator(args.backend, args.workers, args.scheduler)  # fails before the store is touched
    try:
        with _store(args.store) as store:
            progress = _Progress(args.max_evals, enabled=not args.no_progress)
            try:
                run = jobs.optimize_now(store, task, evaluator, progress, **_submit_kwargs(args))
            finally:
                progress.close()
    finally:
        evaluator.close()
    _emit(_result(run), args.json, _print_result)
    return 0


def _optimize_family(args) -> int:
    """--speeds a,b,c: optimize each speed in turn, warm-starting from the previous result."""
    try:
        speeds = [float(v) for v in args.speeds.split(",")]
    except ValueError:
        raise CmrtError(f"--speeds must be comma-separated numbers, got '{args.speeds}'") from None
    if args.speed is not None or isinstance(args.init, int):
        raise CmrtError("--speeds replaces --speed and a run id as --init (each member starts from the previous)")
    tasks = [_opt_task(args, v) for v in speeds]  # validate every speed first
    evaluator = Evaluator(args.backend, args.workers, args.scheduler)
    results, previous = [], None
    try:
        with _store(args.store) as store:
            for task in tasks:
                progress = _Progress(args.max_evals, enabled=not args.no_progress)
                try:
                    kw = _submit_kwargs(args)
                    if previous is not None:
                        kw["init"] = previous
                    if previous is not None:  # stay near the neighbour: one family shape, interpolable
                        kw["sigma0"] = args.family_sigma0
                    run = jobs.optimize_now(store, task, evaluator, progress, **kw)
                finally:
                    progress.close()
                previous = run["id"]
                results.append(_result(run))
                if not args.json:
                    _print_result(results[-1])
    finally:
        evaluator.close()
    if args.json:
        print(json.dumps(results))
    return 0


def cmd_interpolate(args) -> int:
    from cmrt.interpolate import interpolate, to_json

    task = resolve_task(args.task, args.speed, args.set)
    store = _store(args.store, create=False) if args.source == "store" else None
    try:
        r = interpolate(task, args.param, args.source, store)
    finally:
        if store:
            store.close()
    text = to_json(r)
    if args.out:
        try:
            Path(args.out).write_text(text + "\n")
        except OSError as exc:
            raise CmrtError(f"cannot write {args.out}: {exc.strerror}") from None
    if r.extrapolated:
        print(
            f"cmrt: warning: {r.param} = {r.value:g} is outside the optimized range "
            f"[{r.sources[0][0]:g}, {r.sources[1][0]:g}]: extrapolated",
            file=sys.stderr,
        )
    if args.json:
        print(text)
    else:
        src = " and ".join(f"{lab}" for _, lab in r.sources)
        print(
            f"{task.name} {r.param} = {r.value:g}: {'extrapolated' if r.extrapolated else 'interpolated'} "
            f"from {src} (weight {r.weight:.3f})"
        )
        print(
            f"  knots {', '.join(f'{t:.3f}' for t in r.curve.knot_times_s)} s; values "
            f"{', '.join(f'{100 * v:+.2f}' for v in r.curve.values_m)} cm"
            + (f"; written to {args.out}" if args.out else "")
        )
    return 0


def cmd_sequence(args) -> int:
    from cmrt.sequence import load_sequence

    seq = load_sequence(args.file)
    curve = seq.superposed() if args.curve == "superposed" else Cmrt.zero(seq.clip_s)
    t0 = time.perf_counter()
    traj = simulate(seq, curve, record=bool(args.trace))
    ev = evaluate(seq, traj)
    if args.trace:
        _save_npz(args.trace, {**traj.as_npz_dict(), "dof_names": _dof_names(seq)})
    r = {
        "sequence": seq.name,
        "curve": args.curve,
        "clip_s": seq.clip_s,
        "motions": [{"task": m.task.name, "speed": m.task.speed, "start_s": m.start_s} for m in seq.motions],
        **evaluation_dict(ev),
        "wall_s": round(time.perf_counter() - t0, 3),
    }
    if args.json:
        print(json.dumps(r))
    else:
        print(f"{seq.name} ({len(seq.motions)} motions, {seq.clip_s:.2f} s) curve={args.curve}: {_outcome(r)}")
        print(
            f"  objective {r['objective']:.4f}  max |CoP error| {r['max_cop_error_m']:.4f} m  "
            f"final pose error {r['final_pose_error_rad']:.4f} rad"
        )
    return 0


def cmd_worker(args) -> int:
    evaluator = Evaluator(args.backend, args.workers, args.scheduler)
    try:
        with _store(args.store) as store:

            def on_claim(c):
                if not args.json:
                    print(f"worker {jobs.worker_id()}: run {c.run_id} (attempt {c.attempt})", flush=True)

            done = jobs.work(
                store,
                evaluator,
                until_idle=args.until_idle,
                once=args.once,
                stale_after_s=args.stale_after,
                on_claim=on_claim,
            )
    finally:
        evaluator.close()
    _emit({"finished": done}, args.json, f"worker finished runs: {', '.join(map(str, done)) or 'none'}")
    return 0


def _table(rows: list[dict], keys: tuple[str, ...]) -> str:
    def fmt(v):
        if isinstance(v, float):
            return f"{v:.4g}"
        return "-" if v is None else str(v)

    cells = [[k for k in keys]] + [[fmt(r.get(k)) for k in keys] for r in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(keys))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)) for row in cells)


def cmd_jobs(args) -> int:
    with _store(args.store, create=False) as store:
        rows = [
            {
                k: r.get(k)
                for k in ("id", "task", "speed", "status", "worker", "attempt", "evaluations", "heartbeat_at", "error")
            }
            for r in store.runs(status=args.status)
        ]
    _emit(rows, args.json, _table(rows, ("id", "task", "speed", "status", "worker", "attempt", "evaluations")))
    return 0


def cmd_runs(args) -> int:
    with _store(args.store, create=False) as store:
        rows = [query.run_summary(r) for r in store.runs(task=args.task)]
    _emit(
        rows,
        args.json,
        _table(
            rows,
            (
                "id",
                "task",
                "speed",
                "status",
                "seed",
                "best_objective",
                "best_success",
                "baseline_objective",
                "baseline_success",
                "evaluations",
                "stop_reason",
            ),
        ),
    )
    return 0


def cmd_show(args) -> int:
    with _store(args.store, create=False) as store:
        d = query.run_details(store, args.run)
    if args.json:
        print(json.dumps(d))
    else:
        for k, v in d.items():
            if k not in ("task_definition",):
                print(f"{k:20s} {json.dumps(v) if isinstance(v, (dict, list)) else v}")
    return 0


def cmd_best(args) -> int:
    task = resolve_task(args.task, args.speed, args.set)
    with _store(args.store, create=False) as store:
        r = _result(query.best_run(store, task))
    _emit(r, args.json, _print_result)
    return 0


def cmd_export(args) -> int:
    with _store(args.store, create=False) as store:
        text = query.export_run(store, args.run, args.format)
    if args.out:
        try:
            Path(args.out).write_text(text)
        except OSError as exc:
            raise CmrtError(f"cannot write {args.out}: {exc.strerror}") from None
    else:
        sys.stdout.write(text if text.endswith("\n") else text + "\n")
    return 0


def cmd_bench(args) -> int:
    from cmrt.bench import run_bench

    task = resolve_task(args.task, args.speed, args.set)
    backends = tuple(args.backends.split(",")) if args.backends else BACKENDS
    unknown = [b for b in backends if b not in BACKENDS]
    if unknown or args.population < 1 or args.repeat < 1:
        raise CmrtError(f"bad bench options (backends from {', '.join(BACKENDS)}; population, repeat >= 1)")
    r = run_bench(task, args.population, args.repeat, backends, args.workers)
    if args.json:
        print(json.dumps(r))
        return 0
    print(
        f"{r['task']} speed {r['speed']}, population {r['population']}, {r['steps_per_clip']} steps/clip, "
        f"control {r['control_hz']:.0f} Hz ({r['machine']}, median of {r['repeat']} alternating rounds)"
    )
    floor = r["physics_only_s_per_clip"]
    rows = [
        ("physics only (floor)", floor),
        ("batched evaluator", r["batched_s_per_clip"]),
        ("serial, one clip at a time", r["serial_s_per_clip"]),
        (f"robust, per member ({r['robust_members']}/cand.)", r["robust_s_per_member"]),
    ]
    rows += [(f"generation, backend {b}", v) for b, v in r["generation_s_per_clip"].items()]
    for name, v in rows:
        print(f"  {name:32s} {1e3 * v:8.2f} ms/clip   x{v / floor:5.2f}")
    print(f"  batched / floor within each round: median {r['ratio_batched_to_physics']:.2f} "
          f"(min {r['ratio_batched_to_physics_min']:.2f}, max {r['ratio_batched_to_physics_max']:.2f})")
    print(f"  robust ensemble member / plain clip within each round: median {r['ratio_robust_member_to_plain']:.2f}")
    return 0


def cmd_plot(args) -> int:
    from cmrt import plot

    if args.run is None and not args.family and not args.sequence:
        raise CmrtError("plot what? give a RUN, --family TASK or --sequence FILE")
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CmrtError(f"cannot create {out}: {exc.strerror}") from None
    paths = []
    if args.run is not None:
        with _store(args.store, create=False) as store:
            paths += [str(p) for p in plot.plot_run(store, args.run, out)]
    if args.family:
        paths.append(str(plot.plot_family(args.family, out / f"{args.family}_family.png")))
    if args.sequence:
        name = Path(args.sequence).stem
        paths.append(str(plot.plot_sequence(args.sequence, out / f"{name}_sequence.png")))
    _emit({"run_id": args.run, "files": paths}, args.json, "\n".join(paths))
    return 0


def cmd_render(args) -> int:
    from cmrt.render import render

    task = resolve_task(args.task, args.speed, args.set)
    curve, name = resolve_curve(args.curve, task, args.store)
    compare, cname = resolve_curve(args.compare, task, args.store) if args.compare else (None, "")
    if args.frames < 1 or args.fps < 1:
        raise CmrtError("--frames and --fps must be >= 1")
    r = render(task, curve, args.out, compare, (f"{name} CMRT", f"{cname} CMRT"), n_frames=args.frames, fps=args.fps)
    lines = [f"wrote {r['out']} ({r['frames']} frames)"] + [
        f"  {c['label']}: {'lost balance' if c['fell'] else 'balanced'}, objective {c['objective']:.4f}"
        for c in r["clips"]
    ]
    _emit(r, args.json, "\n".join(lines))
    return 0


def _init_arg(value: str) -> str | int:
    if value in ("auto", "none"):
        return value
    try:
        return int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be auto, none or a run id, got '{value}'") from None


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="cmrt", description="Anticipatory balance: center-of-mass reference trajectories.")
    sub = p.add_subparsers(dest="verb", required=True, parser_class=_Parser)
    common = _Parser(add_help=False)
    common.add_argument("--store", metavar="PATH", help=f"SQLite store (default $CMRT_STORE or {DEFAULT_STORE})")

    def add(name, help_, func, json_flag=True):
        sp = sub.add_parser(name, help=help_, parents=[common])
        if json_flag:
            sp.add_argument("--json", action="store_true", help="machine-readable output")
        sp.set_defaults(func=func)
        return sp

    def task_args(sp):
        sp.add_argument("task", help="a shipped task's name (cmrt tasks) or the path of a .toml task file")
        sp.add_argument("--speed", type=float, help="the task's speed parameter (bend: duration T in s)")
        sp.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a task parameter")

    def opt_args(sp):
        sp.add_argument("--seed", type=int, default=1)
        sp.add_argument("--max-evals", type=int, default=3000)
        sp.add_argument("--min-evals", type=int, default=700, help="no slow-convergence stop before this")
        sp.add_argument("--popsize", type=int, default=10)
        sp.add_argument("--stall-generations", type=int, default=20,
                        help="a search whose best improved < 0.1%% over this many generations has stalled: it "
                        "restarts with a doubled population (IPOP) unless it already succeeded past --min-evals")
        sp.add_argument("--sigma0", type=float, default=0.5)
        sp.add_argument("--robust", action="store_true",
                        help="score every candidate on the task's ensemble of perturbed clips ([robust] table)")
        sp.add_argument("--init", type=_init_arg, default="auto", metavar="auto|none|RUN",
                        help="start point: the nearest stored/library CMRT of the task (auto, default), "
                        "the zero CMRT (none), or a stored run's best")

    def backend_args(sp):
        sp.add_argument("--backend", choices=BACKENDS, default="batch")
        sp.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="processes (loky, LocalCluster)")
        sp.add_argument("--scheduler", metavar="ADDRESS", help="dask scheduler (default: a LocalCluster)")

    add("tasks", "list the task files", cmd_tasks)

    s = add("simulate", "simulate one clip of a task with a CMRT", cmd_simulate)
    task_args(s)
    s.add_argument("--curve", default="zero", help="zero | library (the paper's plain CMRT) | library-robust "
                   "| RUN | FILE.json (default zero)")
    s.add_argument("--trace", metavar="FILE.npz", help="save the trajectories")

    s = add("submit", "queue an optimization job", cmd_submit)
    task_args(s)
    opt_args(s)

    s = add("optimize", "run one optimization job in the foreground", cmd_optimize)
    task_args(s)
    opt_args(s)
    s.add_argument("--speeds", metavar="S1,S2,...", help="a speed family, each warm-started from the previous")
    s.add_argument("--family-sigma0", type=float, default=0.15, help="step size of the warm-started members")
    backend_args(s)
    s.add_argument("--no-progress", action="store_true", help="no progress bar")

    s = add("worker", "claim and run queued (and orphaned) jobs", cmd_worker)
    s.add_argument("--until-idle", action="store_true", help="exit when the queue is empty")
    s.add_argument("--once", action="store_true", help="run at most one job")
    s.add_argument(
        "--stale-after",
        type=float,
        default=jobs.DEFAULT_STALE_AFTER_S,
        metavar="SECONDS",
        help="resume a running job whose heartbeat is older than this",
    )
    backend_args(s)

    s = add("jobs", "list jobs and their status", cmd_jobs)
    s.add_argument("--status", choices=("queued", "running", "done", "failed"))

    s = add("runs", "list stored runs", cmd_runs)
    s.add_argument("--task")

    s = add("show", "one run in detail", cmd_show)
    s.add_argument("run", type=int)

    s = add("best", "the best finished run for a task and speed", cmd_best)
    task_args(s)

    s = add("export", "export a run's evaluations", cmd_export, json_flag=False)
    s.add_argument("run", type=int)
    s.add_argument("--format", choices=("json", "csv"), default="json")
    s.add_argument("--out", metavar="FILE")

    s = add(
        "interpolate", "a CMRT for a new speed (or other parameter) from stored or library results", cmd_interpolate
    )
    task_args(s)
    s.add_argument("--param", help="the parameter to interpolate over (default: the task's speed)")
    s.add_argument("--from", dest="source", choices=("library", "store"), default="library")
    s.add_argument("--out", metavar="FILE.json", help="write the CMRT (usable as --curve FILE.json)")

    s = add("sequence", "simulate a sequence of pose changes with superposed (or zero) CMRTs", cmd_sequence)
    s.add_argument("file", help="a shipped sequence's name (four-poses) or the path of a .toml sequence file")
    s.add_argument("--curve", choices=("superposed", "zero"), default="superposed")
    s.add_argument("--trace", metavar="FILE.npz")

    s = add("plot", "figures of a stored run (CoP error, CMRT, convergence)", cmd_plot)
    s.add_argument("run", type=int, nargs="?")
    s.add_argument("--family", metavar="TASK", help="the task's speed family from the library (ABC Fig. 5)")
    s.add_argument("--sequence", metavar="FILE", help="a sequence's superposed CMRTs (ABC Fig. 6)")
    s.add_argument("--out", default="plots", metavar="DIR")

    s = add("render", "render a clip (PNG filmstrip or MP4), optionally beside another", cmd_render)
    task_args(s)
    s.add_argument("--curve", default="library", help="zero | library | RUN | FILE.json (default library)")
    s.add_argument("--compare", help="a second CMRT to show beside it (e.g. zero)")
    s.add_argument("--out", required=True, metavar="FILE.png|FILE.mp4")
    s.add_argument("--frames", type=int, default=8, help="filmstrip frames (PNG)")
    s.add_argument("--fps", type=int, default=30, help="video frame rate (MP4)")

    s = add("bench", "time the physics floor, batched, serial and every backend", cmd_bench)
    s.add_argument("--task", default="bend")
    s.add_argument("--speed", type=float, default=0.4)
    s.add_argument("--set", action="append", metavar="KEY=VALUE")
    s.add_argument("--population", type=int, default=16)
    s.add_argument("--repeat", type=int, default=5)
    s.add_argument("--backends", help=f"comma-separated subset of {','.join(BACKENDS)}")
    s.add_argument("--workers", type=int, default=os.cpu_count() or 1)

    s = add("demo", "the main job: optimize the fast bend into the store, show the result", cmd_demo, json_flag=False)
    backend_args(s)
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
    except BrokenPipeError:  # output piped into `head` and the like
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
