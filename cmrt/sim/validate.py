"""How a CMRT fares on clips it was not optimized for: the seeded validation ensemble.

Every finished run, plain or robust, is replayed on ``ensemble.validation_members``
(pushes at other moments, other prop masses and timings than the robust training grid)
and the figures are stored with it as ``robustness``.
"""

from __future__ import annotations

import math

from cmrt.body.props import prop_class
from cmrt.motion.curve import Cmrt
from cmrt.motion.ensemble import validation_members
from cmrt.motion.task import Task
from cmrt.sim.clip3d import clip_3d
from cmrt.sim.objective import evaluate
from cmrt.sim.simulate import simulate_batch


def robustness(task: Task, curve: Cmrt, threads: int | None = None) -> dict:
    """``validation_total`` members, ``validation_survived`` of them a success (the one verdict rule:
    balance held, motion done on time, plan carried out, settled, goal reached), ``validation_fell``, the
    smallest CoP margin inside the feet over all of them (``min_cop_margin_m``; 0: the CoP reached an end of the
    feet, as it does in every fall) and over the survivors alone (``survived_min_cop_margin_m``: how close a
    success came to that edge). A 3D task's members are its clips one after another (``clip3d.perturbed_3d``: the
    push along the axis its CMRT acts in)."""
    members = validation_members(task, task.robust, prop_class(task.prop).mass_body is not None)
    if task.body != "planar":
        scores = [clip_3d(task, curve, m).evaluation() for m in members]
    else:
        trajs = simulate_batch(task, [curve] * len(members), threads=threads, perturbations=members)
        scores = [evaluate(m.task_variant(task), tr) for m, tr in zip(members, trajs, strict=True)]

    def smallest(evals) -> float | None:
        margins = [e.min_cop_margin_m for e in evals if e.min_cop_margin_m is not None
                   and math.isfinite(e.min_cop_margin_m)]
        return min(margins) if margins else None

    return {
        "validation_total": len(members),
        "validation_survived": sum(bool(e.success) for e in scores),
        "validation_fell": sum(bool(e.fell) for e in scores),
        "min_cop_margin_m": smallest(scores),
        "survived_min_cop_margin_m": smallest([e for e in scores if e.success]),
    }
