"""Figures of a stored run (matplotlib, Agg): ABC Figs. 2-4.

* ``cop_error.png``: CoP error e(t) = p - s over the clip for the zero CMRT and for the
  run's best CMRT, with the support interval and the clip phases (Fig. 2);
* ``cmrt.png``: the best CMRT d(t) with its knots and the preparation / task / decay
  phases marked (Fig. 3);
* ``convergence.png``: every evaluation's objective in order, best so far, the stop
  threshold, falls marked (Fig. 4).

Every line and shaded region is in a legend, and a CoP trace ends where the character lost its balance
(a recorded clip plays the topple out; its CoP then says nothing about balance). Each figure is built by a
``*_figure`` function (tests read its artists) and written by the ``plot_*`` one.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from cmrt import inputs  # noqa: E402
from cmrt.errors import CmrtError  # noqa: E402
from cmrt.motion.curve import Cmrt  # noqa: E402
from cmrt.motion.sequence import load_sequence  # noqa: E402
from cmrt.motion.task import Task
from cmrt.motion.taskfile import load_task  # noqa: E402
from cmrt.service.interpolate import candidates, interpolate, superpose  # noqa: E402
from cmrt.service.query import stored_curve, task_of  # noqa: E402
from cmrt.service.store import Store, StoredEvaluation  # noqa: E402
from cmrt.sim.clip3d import clip_3d, cmrt_axis, cop_trace  # noqa: E402
from cmrt.sim.objective import evaluate  # noqa: E402
from cmrt.sim.report import simulate_report  # noqa: E402
from cmrt.sim.simulate import simulate  # noqa: E402
from cmrt.viz.render import verdict  # noqa: E402


def _save(fig, out: Path) -> Path:
    """Write the figure atomically (``cmrt.inputs.atomic_output``): a failed write says so (one line) and
    leaves no half-written PNG."""
    try:
        with inputs.atomic_output(out, "--out", (".png",)) as tmp:
            fig.savefig(tmp, dpi=110, format="png")
    finally:
        plt.close(fig)
    return out


def _phases(ax, task: Task) -> None:
    """The motion's window [P, P + T], shaded and edged in black."""
    P, T = task.preparation_s, task.duration_s
    ax.axvspan(P, P + T, facecolor="0.9", edgecolor="k", lw=0.8, zorder=0, label=f"motion, P to P + T (T = {T:g} s)")


def _legend(ax) -> None:
    """The axes' legend outside them, on the right, where it hides no curve."""
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)


def until_fall(traj, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(time, values) of a recorded clip up to its fall (all of it when it kept its balance)."""
    n = traj.time_s.size if traj.fall_time_s is None else int(np.searchsorted(traj.time_s, traj.fall_time_s, "right"))
    return traj.time_s[:n], values[:n]


def cop_error_figure(task: Task, curves: list[tuple[str, Cmrt]]):
    """ABC Fig. 2: CoP and support centre over the clip, one panel per CMRT (``cop_series``: a 3D task's along its
    CMRT's axis, a CMRT in x and y's error across too)."""
    fig, axes = plt.subplots(len(curves), 1, figsize=(9.5, 2.4 * len(curves)), sharex=True, squeeze=False)
    for ax, (label, curve) in zip(axes[:, 0], curves, strict=True):
        cop = cop_series(task, curve)
        ax.plot(cop["time_s"], cop["error_cm"], lw=1.2, label=f"CoP error p - s{cop['along']}")
        ax.plot(cop["time_s"], cop["lo_cm"], "k--", lw=0.8, label=f"support edges ({cop['edges']})")
        ax.plot(cop["time_s"], cop["hi_cm"], "k--", lw=0.8)
        if cop["across_cm"] is not None:
            ax.plot(cop["time_s"], cop["across_cm"], lw=1.0, ls="-.", label=f"CoP error, {cop['across']}")
        if cop["fall_s"] is not None:
            ax.axvline(cop["fall_s"], color="r", ls=":", label=f"balance lost ({cop['fall_s']:.2f} s)")
        _phases(ax, task)
        ax.set_title(f"{label}: objective {cop['evaluation'].objective:.3f} ({verdict(cop['evaluation'])})",
                     fontsize=10)
        ax.set_ylabel("p - s (cm)")
        ax.set_xlim(0, task.clip_s + cop["tail_s"])
        if cop["tail_s"] > 0:
            ax.axvspan(task.clip_s, task.clip_s + cop["tail_s"], color="0.95", zorder=0,
                       label="standing tail (not scored)")
        _legend(ax)
    axes[-1, 0].set_xlabel("time (s)")
    fig.tight_layout()
    return fig


def cop_series(task: Task, curve: Cmrt) -> dict:
    """A clip's CoP error from its reference and the support's edges about it (cm), up to a fall, with its
    evaluation, fall time and scored-free tail (s): a planar clip's along x (heel to toe), a 3D clip's along its
    CMRT's axis (``clip3d.cop_trace``, what the dashboard draws: a pose change's forward, a leg lift's sideways) and,
    for a CMRT in x and y, its error across (``across_cm``; None otherwise)."""
    if task.body == "planar":
        traj = simulate(task, curve)
        t, error = until_fall(traj, 100 * (traj.cop_x_m - traj.support_center_x_m))
        return {"time_s": t, "error_cm": error, "lo_cm": until_fall(traj, 100 * (traj.support_lo_x_m
                                                                                   - traj.support_center_x_m))[1],
                "hi_cm": until_fall(traj, 100 * (traj.support_hi_x_m - traj.support_center_x_m))[1],
                "across_cm": None, "along": "", "across": "", "edges": "heel, toe",
                "evaluation": evaluate(task, traj), "fall_s": traj.fall_time_s, "tail_s": task.tail_s}
    c = clip_3d(task, curve)
    axis = cmrt_axis(task)
    trace = cop_trace(task, c, axis)
    along, across = ("forward", "sideways") if axis == 0 else ("sideways", "forward")
    return {"time_s": trace["time_s"], "error_cm": 100 * trace["cop_error_m"], "lo_cm": 100 * trace["support_lo_m"],
            "hi_cm": 100 * trace["support_hi_m"],
            "across_cm": 100 * cop_trace(task, c, 1 - axis)["cop_error_m"] if curve.axes == 2 else None,
            "along": f", {along}", "across": across, "edges": f"foot points, {along}",
            "evaluation": c.evaluation(), "fall_s": c.result.fall_time_s, "tail_s": 0.0}


def plot_cop_error(task: Task, curves: list[tuple[str, Cmrt]], out: Path) -> Path:
    """ABC Fig. 2 written to ``out``."""
    return _save(cop_error_figure(task, curves), out)


def cmrt_figure(task: Task, curve: Cmrt, label: str = "best CMRT"):
    """ABC Fig. 3: the CMRT with its knots and the task's phases."""
    fig, ax = plt.subplots(figsize=(9.5, 2.8))
    t = np.linspace(0, task.clip_s, 400)
    ax.plot(t, 100 * curve.displacement_m(t), lw=1.5, label=label)
    ax.plot(curve.knot_times_s, 100 * np.asarray(curve.values_m), "o", ms=5, label="knots")
    if curve.axes == 2:  # a CMRT in x and y: its displacement across the task's axis, at the same knots
        ax.plot(t, 100 * curve.cross.displacement_m(t), lw=1.5, ls="--", label=f"{label}, across")
        ax.plot(curve.knot_times_s, 100 * np.asarray(curve.cross.values_m), "s", ms=4, label="knots, across")
    _phases(ax, task)
    P, T = task.preparation_s, task.duration_s
    for x, name in ((P / 2, "preparation"), (P + T / 2, "task"), ((P + T + task.clip_s) / 2, "decay")):
        ax.text(x, 1.01, name, transform=ax.get_xaxis_transform(), ha="center", va="bottom", fontsize=8)
    ax.axhline(0, color="0.5", lw=0.6, label="d = 0 (no CMRT)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("d(t) (cm)")
    ax.set_xlim(0, task.clip_s)
    _legend(ax)
    fig.tight_layout()
    return fig


def plot_cmrt(task: Task, curve: Cmrt, out: Path, label: str = "best CMRT") -> Path:
    """ABC Fig. 3 written to ``out``."""
    return _save(cmrt_figure(task, curve, label), out)


def convergence_figure(evaluations: list[StoredEvaluation], threshold: float, title: str):
    """Objective of every evaluation in order (successes, falls, the rest) against the stop threshold."""
    obj = np.array([e.objective for e in evaluations])
    fell = np.array([e.fell for e in evaluations])
    success = np.array([bool(e.success) for e in evaluations])
    other = ~fell & ~success
    idx = np.arange(1, obj.size + 1)
    fig, ax = plt.subplots(figsize=(7, 3))
    ax.semilogy(idx[success], obj[success], ".", ms=3, label="success")
    ax.semilogy(idx[other], obj[other], ".", ms=3, color="0.6", label="balance kept, not a success (penalised)")
    ax.semilogy(idx[fell], obj[fell], "x", ms=3, color="r", label="lost balance (penalised)")
    ax.semilogy(idx, np.minimum.accumulate(obj), "k-", lw=1, label="best so far")
    if threshold > 0:
        ax.axhline(threshold, color="g", ls="--", label=f"stop threshold {threshold:g}")
    ax.set_xlabel("evaluation")
    ax.set_ylabel("objective")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def plot_convergence(evaluations: list[StoredEvaluation], threshold: float, out: Path, title: str) -> Path:
    """The objectives of a run's evaluations written to ``out``."""
    return _save(convergence_figure(evaluations, threshold, title), out)


def run_figure_paths(run_id: int, out_dir: str | Path) -> list[Path]:
    """The files :func:`plot_run` writes for ``run_id`` (so a caller can check them before any work)."""
    return [Path(out_dir) / f"run{run_id}_{kind}.png" for kind in ("cop_error", "cmrt", "convergence")]


def plot_run(store: Store, run_id: int, out_dir: str | Path) -> list[Path]:
    """Write the run's figures to ``out_dir``; returns their paths."""
    run = store.run(run_id)
    if not run.best_cmrt:
        raise CmrtError(f"run {run_id} has no result to plot yet (status {run.status})")
    out = inputs.output_dir(out_dir, "--out")
    task = task_of(run)
    best = stored_curve(run)
    speed = f" T = {task.speed:g} s" if task.speed is not None else ""
    cop_path, cmrt_path, convergence_path = run_figure_paths(run_id, out)
    return [
        plot_cop_error(
            task,
            [("zero CMRT", Cmrt.zero(task.clip_s, task.cmrt_axes)), (f"run {run_id} best CMRT", best)],
            cop_path,
        ),
        plot_cmrt(task, best, cmrt_path, f"run {run_id}: {task.name}{speed}"),
        plot_convergence(
            store.evaluations(run_id),
            run.stop_threshold or 0.0,
            convergence_path,
            f"run {run_id}: {task.name}{speed}, {run.evaluations} evaluations ({run.stop_reason})",
        ),
    ]


def family_figure(task_name: str, between: tuple[float, ...] = (), source: str = "library",
                  store: Store | None = None):
    """ABC Fig. 5: CMRTs optimized at several speeds (solid) and interpolated between them (dashed)."""
    base = load_task(task_name)
    if base.speed_param is None:
        raise CmrtError(f"task '{task_name}' has no speed parameter for a family figure")
    pts = candidates(base, base.speed_param, source, store)
    if len(pts) < 2:
        raise CmrtError(f"need two {source} results for '{task_name}' at different speeds; found {len(pts)}")
    speeds = [v for v, _, _ in pts]
    between = between or tuple((a + b) / 2 for a, b in zip(speeds, speeds[1:], strict=False))
    fig, ax = plt.subplots(figsize=(10, 3.6))
    colors = plt.cm.viridis(np.linspace(0, 0.9, len(speeds) + len(between)))
    t = np.linspace(0, base.clip_s, 400)
    rows = sorted([(v, "opt", c) for v, c, _ in pts] + [(v, "int", None) for v in between], key=lambda r: r[0])
    for i, (color, (v, kind, curve)) in enumerate(zip(colors, rows, strict=True)):
        task = base.with_speed(v)
        if kind == "int":
            curve = interpolate(task, source=source, store=store).curve
        ev = simulate_report(task, curve, kind)  # either body's clip and score
        ax.plot(t, 100 * curve.displacement_m(t), "-" if kind == "opt" else "--", color=color, lw=1.4,
                label=f"T={v:g} {'optimized' if kind == 'opt' else 'interpolated'} e={ev['objective']:.3f}"
                      f"{'' if ev['success'] else ' (not a success)'}")
        ax.axvline(task.preparation_s + v, color=color, lw=0.6,
                   label="motion ends, P + T (the curve's colour)" if i == 0 else "_nolegend_")
    ax.axvline(base.preparation_s, color="k", lw=1.0, label="motion starts, P")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("d(t) (cm)")
    ax.set_title(f"{task_name}: optimized (solid) and interpolated (dashed) CMRTs", fontsize=10)
    _legend(ax)
    fig.tight_layout()
    return fig


def plot_family(
    task_name: str, out: Path, between: tuple[float, ...] = (), source: str = "library", store: Store | None = None
) -> Path:
    """ABC Fig. 5 written to ``out``."""
    return _save(family_figure(task_name, between, source, store), out)


def sequence_figure(seq_file: str):
    """ABC Fig. 6: the motions' shifted CMRTs and their sum, and the CoP error with zero vs superposed CMRTs
    (each up to its fall)."""
    seq = load_sequence(seq_file)
    sup = superpose(seq)
    t = np.linspace(0, seq.clip_s, 800)
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(10, 5), sharex=True)
    for (off, c), m in zip(sup.parts, seq.motions, strict=True):
        ax1.plot(
            t, 100 * c.displacement_m(t - off), "--", lw=1, label=f"{m.task.name} T={m.task.speed:g} @ {m.start_s:g} s"
        )
    ax1.plot(t, 100 * sup.displacement_m(t), "k-", lw=1.8, label="superposed")
    ax1.set_ylabel("d(t) (cm)")
    for i, (label, curve) in enumerate((("zero CMRTs", Cmrt.zero(seq.clip_s)), ("superposed CMRTs", sup))):
        cop = cop_series(seq, curve)  # either body's: a 3D sequence's forward
        ax2.plot(cop["time_s"], cop["error_cm"], lw=1, color=f"C{i}",
                 label=f"{label}: e={cop['evaluation'].objective:.3f} ({verdict(cop['evaluation'])})")
        if cop["fall_s"] is not None:
            ax2.axvline(cop["fall_s"], color=f"C{i}", ls=":", lw=1.2,
                        label=f"{label}: balance lost ({cop['fall_s']:.2f} s)")
    for i, m in enumerate(seq.motions):
        for ax in (ax1, ax2):
            ax.axvspan(m.start_s, m.start_s + m.task.duration_s, color="0.92", zorder=0,
                       label="a motion's window" if i == 0 else "_nolegend_")
    ax2.set_ylabel("p - s (cm)")
    ax2.set_xlabel("time (s)")
    _legend(ax1)
    _legend(ax2)
    ax1.set_title(f"sequence {seq.name}", fontsize=10)
    fig.tight_layout()
    return fig


def plot_sequence(seq_file: str, out: Path) -> Path:
    """ABC Fig. 6 written to ``out``."""
    return _save(sequence_figure(seq_file), out)
