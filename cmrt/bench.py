"""``cmrt bench``: where the time of a CMRT evaluation goes, measured in one run.

(a) the floor: the clip's physics alone (clip and standing tail, as many steps as an
    evaluation) for N simulations on a ``mujoco.batch.Batch`` (all cores' threads, zero
    control, from the settled state);
(b) the batched evaluator: N candidates in lockstep with the compiled controller;
(c) per-candidate serial evaluation (one clip after another, one thread);
(d) one full generation of N candidates with each optimizer backend;
(e) the same N candidates scored robustly: each on the task's ensemble (``cmrt.ensemble``),
    all N x members clips in one lockstep batch - the cost per member against a plain clip's;
(f) optionally a whole optimization (the caller's ``optimize``: ``cmrt bench`` runs ``cmrt optimize
    TASK --seed 1 --init none`` into a throwaway store) against its evaluations x the floor per clip (the floor is
    already measured on all cores' threads, so that product is evaluations x floor / cores).

(a)-(c) and (e) run in ``repeat`` alternating rounds and each round's batched/floor ratio is
taken within the round: these machines are noisy, so the figures are the median (and
min, max) over rounds, and ratios from one run are what to compare, not seconds across
runs.
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable

import mujoco
import mujoco.batch
import numpy as np

from cmrt.character import character
from cmrt.control import ControllerConfig
from cmrt.curve import Cmrt
from cmrt.ensemble import training_members
from cmrt.errors import CmrtError
from cmrt.library import library_curve
from cmrt.parallel import BACKENDS, Evaluator, evaluate_candidate
from cmrt.props import prop_class
from cmrt.simulate import settled_state, simulate_batch
from cmrt.task import Task

# (evaluations, wall seconds) of one full optimization of a task: supplied by the caller (the CLI runs
# ``jobs.optimize_now``; this module sits below the store and the service)
OptimizeFn = Callable[[Task], tuple[int, float]]


def _candidates(task: Task, n: int) -> list[np.ndarray]:
    """Small perturbations of the library optimum (most clips run to the end), or of the flat start."""
    try:
        base = library_curve(task).to_params()
    except CmrtError:
        base = np.zeros(8)
    rng = np.random.default_rng(0)
    return [base + rng.normal(0.0, 0.02, base.size) for _ in range(n)]


def run_bench(task: Task, population: int = 16, repeat: int = 5, backends=BACKENDS, workers: int = 2,
              optimize: OptimizeFn | None = None) -> dict:
    """Time the physics floor, the batched and serial evaluators and a generation on each backend, in
    alternating rounds (ratios within a round: this VM's speed drifts); what ``cmrt bench`` prints.
    ``optimize``: also time one full optimization of ``task`` against its evaluations x floor."""
    m = character().model
    n_steps = int(round((task.clip_s + task.tail_s) / m.opt.timestep))  # what an evaluation simulates
    threads = os.cpu_count() or 1
    xs = _candidates(task, population)
    curves = [Cmrt.from_params(x, task.clip_s) for x in xs]
    state = settled_state(task, ControllerConfig())

    def physics() -> None:
        batch = mujoco.batch.Batch(m, nsim=population, nthread=threads, persistent=True)
        for k, v in state.items():
            batch.bind(k)[:] = v
        batch.forward()
        for _ in range(n_steps):
            batch.step()

    robust = task.with_robust()
    members = training_members(robust, robust.robust, prop_class(task.prop).mass_body is not None)
    ensemble_curves = [c for c in curves for _ in members]
    rounds: dict[str, list[float]] = {"physics": [], "batched": [], "serial": [], "robust": []}
    generations: dict[str, list[float]] = {}

    def timed(fn) -> float:
        t0 = time.perf_counter()
        fn()
        return time.perf_counter() - t0

    simulate_batch(task, curves[:2])  # warm-up: settled state, compiled controller
    fells = [tr.fell for tr in simulate_batch(task, curves)]
    for _ in range(repeat):  # alternate so machine noise hits each figure alike
        rounds["physics"].append(timed(physics))
        rounds["batched"].append(timed(lambda: simulate_batch(task, curves)))
        rounds["serial"].append(timed(lambda: [evaluate_candidate(task, x) for x in xs]))
        rounds["robust"].append(timed(lambda: simulate_batch(robust, ensemble_curves,
                                                             perturbations=members * population)))
    for b in backends:  # one backend alive at a time: idle workers/clusters would steal CPU
        with Evaluator(b, workers=workers) as ev:
            ev(task, xs[:2])  # warm-up: worker processes, clusters, per-process caches
            generations[b] = [timed(lambda ev=ev: ev(task, xs)) for _ in range(repeat)]

    ratios = np.array(rounds["batched"]) / np.array(rounds["physics"])
    per = {k: float(np.median(v)) / population for k, v in rounds.items()}
    out = {
        "task": task.name, "speed": task.speed, "population": population, "steps_per_clip": n_steps,
        "control_hz": 1.0 / (m.opt.timestep * ControllerConfig().control_every),
        "candidates_that_fell": int(sum(fells)),
        "physics_only_s_per_clip": per["physics"],
        "batched_s_per_clip": per["batched"],
        "serial_s_per_clip": per["serial"],
        "ratio_batched_to_physics": float(np.median(ratios)),
        "ratio_batched_to_physics_min": float(ratios.min()),
        "ratio_batched_to_physics_max": float(ratios.max()),
        "ratio_serial_to_physics": float(np.median(np.array(rounds["serial"]) / np.array(rounds["physics"]))),
        "robust_members": len(members),
        "robust_s_per_member": per["robust"] / len(members),
        # per clip, within each round: an ensemble member against a plain candidate's clip
        "ratio_robust_member_to_plain": float(np.median(np.array(rounds["robust"]) / len(members)
                                                        / np.array(rounds["batched"]))),
        "generation_s_per_clip": {b: float(np.median(v)) / population for b, v in generations.items()},
        "machine": f"{platform.machine()}, {threads} cores, mujoco {mujoco.__version__}",
        "repeat": repeat,
    }
    if optimize is not None:
        evaluations, wall_s = optimize(task)
        floor_s = evaluations * out["physics_only_s_per_clip"]
        out.update({"optimize_evaluations": evaluations, "optimize_wall_s": wall_s, "optimize_floor_s": floor_s,
                    "ratio_optimize_to_floor": wall_s / floor_s if floor_s > 0 else float("nan")})
    return out
