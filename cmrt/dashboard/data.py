"""What the dashboard shows, as JSON-safe values: the pages draw it and scripts read the same endpoints.

Every function takes a store opened read-only (``open_store(path, readonly=True)``, as the read verbs do) and
only reads it. The figures come from the code the CLI uses: run summaries from ``service.query`` (and the CLI's
``improvement_over_zero``), CoP traces cut at the fall as ``viz.plot`` draws them, verdicts and task labels from
``viz.render``, clips from ``viz.render.render``. Simulations (CoP traces, plausibility, interpolated members)
are kept in a small in-memory cache keyed by what decides them (the task's definition and the curve).
"""

from __future__ import annotations

import hashlib
import json
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cmrt import inputs
from cmrt.dashboard import clipcache
from cmrt.errors import CmrtError
from cmrt.motion.curve import Cmrt
from cmrt.motion.task import Task
from cmrt.service.interpolate import blend
from cmrt.service.query import run_details, run_summary, search_summary, stored_curve, task_of
from cmrt.service.store import Run, Store, StoredEvaluation
from cmrt.sim.clip3d import clip_3d, cmrt_axis, cop_trace
from cmrt.sim.objective import evaluate
from cmrt.sim.report import evaluation_dict, spatial_dict
from cmrt.sim.simulate import simulate
from cmrt.viz.plot import until_fall
from cmrt.viz.render import render, task_label, verdict
from cmrt.viz.render3d import render_3d

CURVE_SAMPLES = 200  # points of a CMRT curve d(t) sent to the page
MAX_TRACE_POINTS = 1500  # a CoP trace is thinned to at most this many points (a 2 ms step: every second one)
MAX_COMPARED_RUNS = 12
#: the figures the one verdict rule judges (docs/physics.md, *Success*) and the fastest joint, with their limits: a
#: number, or the key of the report's task-dependent bound (the same for both clips of a run: one task)
PLAUSIBILITY = (
    ("peak_normal_force_bw", "peak ground force (x body weight)", "peak_normal_force_bw"),
    ("airborne_s", "airborne (s)", "airborne_s"),
    ("max_joint_speed_rad_s", "fastest joint (rad/s)", 25.0),
    ("min_cop_margin_m", "smallest CoP margin to the feet's edge (m, at least)", "min_cop_margin_m"),
    ("max_plan_cop_error_m", "planned vs executed CoP (m)", "max_plan_cop_error_m"),
    ("tracking_error_rad", "RMS tracking error over the motion (rad)", "tracking_bound_rad"),
    ("final_pose_error_rad", "final pose error (rad)", "final_pose_error_rad"),
    ("timing_lag_s", "timing lag of the motion (s)", "timing_lag_bound_s"),
)


def _limit(limit: float | str, report: dict) -> float | None:
    """A figure's limit: a number as it stands, a key read from the verdict's bounds or the report itself."""
    if not isinstance(limit, str):
        return limit
    bounds = report.get("verdict_bounds") or {}
    return bounds.get(limit, report.get(limit))


def _either(limits) -> float | None:
    """The first known limit of a figure over the clips: a clip that fell has no tracking or timing bound (its
    motion was not done), the other clip of the page has."""
    return next((v for v in limits if v is not None), None)


class NotFound(CmrtError):
    """What a URL names is not there (an unknown run id): a 404, not a damaged store."""


@dataclass
class SimCache:
    """Simulated results by key, the most recent ``size`` kept; one simulation at a time (2 cores shared with
    the workers: parallel requests would only slow each other and them)."""

    size: int = 32
    _items: OrderedDict = field(default_factory=OrderedDict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def get(self, key: str, make: Callable[[], dict]) -> dict:
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
            value = make()
            self._items[key] = value
            while len(self._items) > self.size:
                self._items.popitem(last=False)
            return value


def _key(*parts: object) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def find_run(store: Store, run_id: int) -> Run:
    """The run ``run_id``, or :class:`NotFound`."""
    if not store.has_run(run_id):
        raise NotFound(f"no run {run_id} in this store")
    return store.run(run_id)


def _progress(run: Run) -> dict:
    """How far a run is: evaluations of its budget, generations, and how old its worker's heartbeat is."""
    return {"evaluations": run.evaluations, "max_evals": run.max_evals, "generations": run.generations,
            "fraction": min(1.0, run.evaluations / run.max_evals) if run.max_evals else None,
            "heartbeat_at": run.heartbeat_at, "worker": run.worker, "attempt": run.attempt}


def run_row(run: Run) -> dict:
    """One line of the runs table: ``cmrt runs``'s columns, progress, improvement over no CMRT, robustness."""
    row = run_summary(run)
    row.update(
        progress=_progress(run), restarts=run.restarts or 0, robust=run.robust is not None,
        robustness=run.robustness, init=run.init_source, created_at=run.created_at, finished_at=run.finished_at,
        improvement_over_zero=(None if run.baseline_objective is None or run.best_objective is None
                               else run.baseline_objective - run.best_objective),
        error=run.error, search=search_summary(run),
    )
    return inputs.json_safe(row)


def runs_table(store: Store) -> dict:
    """Every run, oldest first, and whether any is still queued or running (the page polls while so)."""
    with store.snapshot():
        runs = store.runs()
    rows = [run_row(r) for r in runs]
    return {"store": str(store.path), "runs": rows,
            "active": any(r["status"] in ("queued", "running") for r in rows)}


def restart_starts(evaluations: list[StoredEvaluation], restarts: int) -> list[int]:
    """Where (1-based evaluation index) each of the run's ``restarts`` began, as the store lets us see it: a
    restart is a new CMA-ES, so its first generation has another population or a reset step size. The store
    keeps the count, not the places; the ``restarts`` boundaries most like one are returned (a new population
    first, then the largest jump of the generations' mean objective)."""
    if restarts <= 0 or not evaluations:
        return []
    gens: dict[int, list[StoredEvaluation]] = {}
    for e in evaluations:
        gens.setdefault(e.gen, []).append(e)
    order = sorted(gens)
    starts, scores, index = [], [], 1 + len(gens[order[0]])
    for prev, gen in zip(order, order[1:], strict=False):
        size_changed = len(gens[gen]) != len(gens[prev])
        jump = float(np.median([e.objective for e in gens[gen]]) / max(np.median([e.objective for e in gens[prev]]),
                                                                         1e-12))
        starts.append(index)
        scores.append((size_changed, jump))
        index += len(gens[gen])
    ranked = sorted(range(len(starts)), key=lambda i: scores[i], reverse=True)[:restarts]
    return sorted(starts[i] for i in ranked)


def _convergence(run: Run, evaluations: list[StoredEvaluation]) -> dict:
    """Every candidate's objective in order, successes and falls marked, best so far, threshold, restarts."""
    obj = [e.objective for e in evaluations]
    best = np.minimum.accumulate(obj).tolist() if obj else []
    return inputs.json_safe({
        "objective": obj, "success": [bool(e.success) for e in evaluations], "fell": [e.fell for e in evaluations],
        "gen": [e.gen for e in evaluations], "best_so_far": best, "threshold": run.stop_threshold,
        "restarts": restart_starts(evaluations, run.restarts or 0),
    })


def curve_points(curve: Cmrt) -> dict:
    """A CMRT sampled over its clip (cm, as the figures plot it) and its knots; a CMRT in x and y's displacement
    across the task's axis too (``cross_displacement_cm``, ``cross_knot_values_cm``)."""
    t = np.linspace(0.0, curve.clip_s, CURVE_SAMPLES)
    out = {"time_s": t.tolist(), "displacement_cm": (100 * curve.displacement_m(t)).tolist(),
           "knot_times_s": list(curve.knot_times_s), "knot_values_cm": [100 * v for v in curve.values_m]}
    if curve.axes == 2:
        out["cross_displacement_cm"] = (100 * curve.cross.displacement_m(t)).tolist()
        out["cross_knot_values_cm"] = [100 * v for v in curve.cross.values_m]
    return out


def _task_info(task: Task) -> dict:
    return {"label": task_label(task), "preparation_s": task.preparation_s, "duration_s": task.duration_s,
            "clip_s": task.clip_s, "tail_s": task.tail_s}


def run_page(store: Store, run_id: int) -> dict:
    """A run: its details (``cmrt show``), convergence, best CMRT against the zero one, the task definition."""
    with store.snapshot():
        run = find_run(store, run_id)
        details = run_details(store, run_id)
        evaluations = store.evaluations(run_id)
    task = task_of(run)
    best = curve_points(stored_curve(run)) if run.best_cmrt else None
    return inputs.json_safe({
        "store": str(store.path), "run": run_row(run), "details": details, "task": _task_info(task),
        "task_definition": run.task_definition,
        "convergence": _convergence(run, evaluations), "best_cmrt": best,
        "zero_cmrt": curve_points(Cmrt.zero(task.clip_s, task.cmrt_axes)),
    })


def _trace(task: Task, curve: Cmrt, label: str) -> dict:
    """One clip's CoP error p - s and support edges (cm) up to its fall, thinned, with its score (a 3D clip's
    along its CMRT's axis: ``_trace_3d``)."""
    if task.body != "planar":
        return _trace_3d(task, curve, label)
    traj = simulate(task, curve)
    ev = evaluate(task, traj)
    step = max(1, int(np.ceil(traj.time_s.size / MAX_TRACE_POINTS)))
    t, err = until_fall(traj, 100 * (traj.cop_x_m - traj.support_center_x_m))
    _, lo = until_fall(traj, 100 * (traj.support_lo_x_m - traj.support_center_x_m))
    _, hi = until_fall(traj, 100 * (traj.support_hi_x_m - traj.support_center_x_m))
    report = evaluation_dict(ev)
    return inputs.json_safe({
        "label": label, "verdict": verdict(ev), "objective": ev.objective, "fall_time_s": traj.fall_time_s,
        "time_s": t[::step].tolist(), "cop_error_cm": err[::step].tolist(), "support_lo_cm": lo[::step].tolist(),
        "support_hi_cm": hi[::step].tolist(),
        "plausibility": {k: report.get(k) for k, _, _ in PLAUSIBILITY},
        "limits": {k: _limit(lim, report) for k, _, lim in PLAUSIBILITY},
        "failed_rules": list(ev.failed_rules),
    })


def _trace_3d(task: Task, curve: Cmrt, label: str) -> dict:
    """A 3D clip's CoP error and support edges along its CMRT's axis (``clip3d.cop_trace``: a leg lift's sideways,
    a pose change's forward; a CMRT in x and y's error across too), with its report's figures."""
    c = clip_3d(task, curve)
    report = spatial_dict(task, c, curve, label)
    axis = cmrt_axis(task)
    trace = cop_trace(task, c, axis)
    step = max(1, int(np.ceil(trace["time_s"].size / MAX_TRACE_POINTS)))
    across = {}
    if task.cmrt_axes == 2:
        across = {"cross_axis": "xy"[1 - axis],
                  "cross_cop_error_cm": (100 * cop_trace(task, c, 1 - axis)["cop_error_m"][::step]).tolist()}
    return inputs.json_safe(across | {
        "label": label, "verdict": verdict(c.evaluation()), "objective": c.objective,
        "fall_time_s": c.result.fall_time_s,
        "time_s": trace["time_s"][::step].tolist(), "cop_error_cm": (100 * trace["cop_error_m"][::step]).tolist(),
        "support_lo_cm": (100 * trace["support_lo_m"][::step]).tolist(),
        "support_hi_cm": (100 * trace["support_hi_m"][::step]).tolist(),
        "plausibility": {k: report.get(k) for k, _, _ in PLAUSIBILITY},
        "limits": {k: _limit(lim, report) for k, _, lim in PLAUSIBILITY},
        "failed_rules": list(c.failed_rules), "axis": "xy"[axis],
    })


def run_traces(store: Store, run_id: int, cache: SimCache) -> dict:
    """The CoP-error traces of the zero and the best CMRT, and their plausibility figures (simulated once per
    run and curve: a few seconds the first time)."""
    run = find_run(store, run_id)
    if not run.best_cmrt:
        raise NotFound(f"run {run_id} has no result yet (status {run.status})")

    def make() -> dict:
        task = task_of(run)
        best = stored_curve(run)
        clips = [_trace(task, Cmrt.zero(task.clip_s, task.cmrt_axes), "zero CMRT"),
                 _trace(task, best, f"run {run_id} best CMRT")]
        return {"run_id": run_id, "task": _task_info(task), "clips": clips,
                "plausibility_fields": [{"key": k, "label": lab, "limit": _either(c["limits"][k] for c in clips)}
                                        for k, lab, _ in PLAUSIBILITY]}

    return cache.get(_key("traces", run.task_definition, run.best_cmrt), make)


def _interpolated(a: tuple[Run, Task, Cmrt], b: tuple[Run, Task, Cmrt], cache: SimCache) -> dict | None:
    """The member halfway between two runs of a speed family (ABC 4.2: their knots blended), scored."""
    (ra, ta, ca), (rb, tb, cb) = a, b
    if ta.speed is None or tb.speed is None or ta.speed == tb.speed or abs(ta.clip_s - tb.clip_s) > 1e-12:
        return None
    if {k: v for k, v in ta.params.items() if k != ta.speed_param} != \
            {k: v for k, v in tb.params.items() if k != tb.speed_param}:
        return None
    speed = (ta.speed + tb.speed) / 2
    task, curve = ta.with_speed(speed), blend(ca, cb, 0.5)

    def make() -> dict:
        if task.body != "planar":
            c = clip_3d(task, curve)
            objective, text, success = c.objective, verdict(c.evaluation()), c.success
        else:
            ev = evaluate(task, simulate(task, curve, record=False))
            objective, text, success = ev.objective, verdict(ev), ev.success
        return inputs.json_safe({"label": f"interpolated {task_label(task)} (runs {ra.id}, {rb.id})",
                                 "speed": speed, "objective": objective, "verdict": text,
                                 "success": success, "curve": curve_points(curve)})

    return cache.get(_key("interpolated", task.to_dict(), curve.to_dict()), make)


def compare(store: Store, run_ids: list[int], cache: SimCache) -> dict:
    """Several runs' best CMRTs and objectives side by side; for runs of one task at different speeds (a speed
    family) also the members halfway between neighbours, blended from their CMRTs and scored."""
    if not run_ids:
        raise CmrtError("name the runs to compare: ?runs=1,2,3")
    if len(run_ids) > MAX_COMPARED_RUNS:
        raise CmrtError(f"compare at most {MAX_COMPARED_RUNS} runs, got {len(run_ids)}")
    with store.snapshot():
        runs = [find_run(store, i) for i in dict.fromkeys(run_ids)]
    members, shown_runs = [], []
    for run in runs:
        task = task_of(run)
        curve = stored_curve(run) if run.best_cmrt else None
        shown_runs.append({**run_row(run), "label": f"run {run.id}: {task_label(task)}",
                           "curve": curve_points(curve) if curve else None})
        if curve is not None and run.task == runs[0].task:
            members.append((run, task, curve))
    members.sort(key=lambda m: (m[1].speed is None, m[1].speed or 0.0))
    between = [m for a, b in zip(members, members[1:], strict=False) if (m := _interpolated(a, b, cache))]
    return inputs.json_safe({"runs": shown_runs, "interpolated": between})


def clip_name(run: Run, fps: int) -> str:
    """A run's clip in the cache: ``run<id>-<key>.mp4``, named by what decides its pixels, so that a changed best
    CMRT is rendered anew."""
    return f"run{run.id}-{_key(run.task_definition, run.best_cmrt, fps)}.mp4"


_render_lock = threading.Lock()  # one render at a time: OpenGL context and CPU


def clip(store: Store, run_id: int, fps: int, cache_dir: Path) -> bytes:
    """The run's MP4 (zero CMRT beside its best), rendered on first request into the dashboard's own cache
    (:mod:`cmrt.dashboard.clipcache`: read back only as a file it wrote). CmrtError (one line) where no OpenGL
    backend loads or the cache is not one this user owns."""
    run = find_run(store, run_id)
    if not run.best_cmrt:
        raise NotFound(f"run {run_id} has no result to render yet (status {run.status})")
    task, best = task_of(run), stored_curve(run)
    draw = render if task.body == "planar" else render_3d  # a 3D clip: each clip's front over its side view

    def make(out: Path) -> None:
        draw(task, best, out, Cmrt.zero(task.clip_s, task.cmrt_axes), (f"run {run_id} best CMRT", "zero CMRT"), fps=fps)

    with _render_lock:
        return clipcache.cached(cache_dir, clip_name(run, fps), make)
