"""CMRTs for new motion speeds (or masses) from stored ones, and superposed sequences.

ABC 4.2: "we interpolate the optimal solutions found at adjacent speeds ... using the
knot values and control points". For a requested value v of a task parameter (the
speed by default), the two results adjacent to v (from the store or the library, for
the same task with every other physical parameter equal) are blended linearly in v,
knot times and control values alike. Beyond the optimized range the two nearest results
are extrapolated linearly, flagged ``extrapolated``, and knots that would leave the clip
or cross are pushed back to valid ones (at least MIN_GAP_S apart inside the clip).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from cmrt.errors import CmrtError
from cmrt.motion.curve import MIN_GAP_S, N_KNOTS, Cmrt
from cmrt.motion.library import KnownCmrt, library_curve
from cmrt.motion.sequence import SequenceTask, SuperposedCmrt
from cmrt.motion.task import Task, active_params
from cmrt.service.known import SOURCES, known_cmrts
from cmrt.service.store import Store

IGNORED_PARAMS = ("stop_threshold",)  # do not change the physics of a clip


@dataclass(frozen=True)
class Interpolated:
    """An interpolated (or extrapolated) CMRT and where it came from."""

    curve: Cmrt
    param: str
    value: float
    sources: tuple[tuple[float, str], ...]  # (parameter value, where the CMRT came from)
    weight: float  # 0 at the first source, 1 at the second
    extrapolated: bool
    task: str = ""  # the task's name: written into the JSON, so --curve FILE refuses it for another task


def blend(a: Cmrt, b: Cmrt, w: float) -> Cmrt:
    """(1 - w) a + w b in knot times and values (a CMRT in two axes: its cross values too, a one-axis CMRT's
    being 0 across); exact at w = 0 and w = 1."""
    if abs(a.clip_s - b.clip_s) > 1e-12:
        raise CmrtError(f"cannot interpolate CMRTs of {a.clip_s:g} s and {b.clip_s:g} s clips")
    t = (1.0 - w) * np.asarray(a.knot_times_s) + w * np.asarray(b.knot_times_s)
    v = (1.0 - w) * np.asarray(a.values_m) + w * np.asarray(b.values_m)
    cross = None
    if a.axes == 2 or b.axes == 2:
        cross = tuple(map(float, (1.0 - w) * np.asarray(a.cross.values_m) + w * np.asarray(b.cross.values_m)))
    return Cmrt(a.clip_s, tuple(map(float, _valid_knots(t, a.clip_s))), tuple(map(float, v)), cross)


def _valid_knots(t: np.ndarray, clip_s: float) -> np.ndarray:
    """Ordered, >= MIN_GAP_S apart, inside the clip (unchanged when already so)."""
    if t[0] >= MIN_GAP_S and np.all(np.diff(t) >= MIN_GAP_S) and t[-1] <= clip_s - MIN_GAP_S:
        return t
    t = np.sort(t)
    lo = MIN_GAP_S * np.arange(1, N_KNOTS + 1)
    hi = clip_s - MIN_GAP_S * np.arange(N_KNOTS, 0, -1)
    t = np.clip(t, lo, hi)
    for i in range(1, N_KNOTS):
        t[i] = max(t[i], t[i - 1] + MIN_GAP_S)
    return t


def _physics(params: dict, skip: str, planned: bool = False) -> dict:
    return {k: v for k, v in active_params(params, planned).items() if k != skip and k not in IGNORED_PARAMS}


def candidates(task: Task, param: str, source: str, store: Store | None = None) -> list[tuple[float, Cmrt, str]]:
    """(value of ``param``, CMRT, label) of every successful CMRT of the task's own kind (plain or robust)
    from ``source`` that matches ``task`` in every other physical parameter; per value the lowest objective
    (the oldest on ties)."""
    if source not in SOURCES:
        raise CmrtError(f"--from must be store or library, got '{source}'")
    if source == "store" and store is None:
        raise CmrtError("interpolating from the store needs a store")
    want = _physics(task.params, param, bool(task.steps))
    best: dict[float, KnownCmrt] = {}
    for known in known_cmrts(task, store, sources=(source,), robust=task.robust.enabled, same_clip=False):
        if known.steps != task.steps or _physics(known.params, param, bool(known.steps)) != want:  # its plan's
            continue
        v = known.params[param]
        if source == "library" or v not in best or known.objective < best[v].objective:
            best[v] = known  # the library has one entry per value (the last one written wins)
    label = (lambda k, v: f"library {task.name} {param}={v:g}") if source == "library" else (
        lambda k, v: f"{k.source} {param}={v:g}")
    return [(v, best[v].curve, label(best[v], v)) for v in sorted(best)]


def interpolate(
    task: Task, param: str | None = None, source: str = "library", store: Store | None = None
) -> Interpolated:
    """The CMRT for ``task`` at its current value of ``param`` (default: its speed)."""
    param = param or task.speed_param
    if param is None:
        raise CmrtError(f"task '{task.name}' has no speed parameter: name one with --param")
    if param not in task.params:
        raise CmrtError(f"task '{task.name}' has no parameter '{param}' to interpolate over")
    value = task.params[param]
    pts = candidates(task, param, source, store)
    if len(pts) < 2:
        raise CmrtError(
            f"need two {source} results for '{task.name}' across {param} with the other parameters "
            f"equal; found {len(pts)}"
        )
    values = np.array([p[0] for p in pts])
    i = int(np.clip(np.searchsorted(values, value) - 1, 0, len(pts) - 2))
    (va, ca, la), (vb, cb, lb) = pts[i], pts[i + 1]
    w = (value - va) / (vb - va)
    extrapolated = bool(value < values[0] or value > values[-1])
    return Interpolated(blend(ca, cb, w), param, value, ((va, la), (vb, lb)), float(w), extrapolated, task.name)


def to_json(r: Interpolated) -> str:
    """The result as JSON; its ``cmrt`` is a CMRT file usable as ``--curve FILE.json``."""
    return json.dumps(
        {
            "task": r.task,
            "param": r.param,
            "value": r.value,
            "weight": r.weight,
            "extrapolated": r.extrapolated,
            "sources": [{"value": v, "from": s} for v, s in r.sources],
            "cmrt": r.curve.to_dict(),
        }
    )


def superpose(seq: SequenceTask, curves: list[Cmrt | None] | None = None) -> SuperposedCmrt:
    """A sequence's CMRT (ABC 4.2): each motion's CMRT - given, else the library's, else interpolated from
    the library - shifted to the motion's start, summed."""
    parts = []
    for i, m in enumerate(seq.motions):
        curve = curves[i] if curves else None
        if curve is None:
            try:
                curve = library_curve(m.task)
            except CmrtError:
                curve = interpolate(m.task).curve
        parts.append((m.offset_s, curve))
    return SuperposedCmrt(seq.clip_s, parts)
