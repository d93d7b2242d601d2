"""``cmrt bench``: where the time of a CMRT evaluation goes, measured in one run.

(a) the floor: the same clips' physics alone. The batched evaluator's clips are run once recording
    the torques it applied (``simulate_batch(..., record=True)``: ``Trajectory.ctrl_nm``); the floor
    replays them open loop on ``mujoco.batch.Batch`` from the same settled state - the torques written
    into ``ctrl`` at each control step (the evaluation holds them in between), each clip for exactly
    the steps it ran in the evaluation (a clip that fell stops at its fall), split into the same groups
    on the same threads as ``simulate_batch`` (one group per core, a one-thread Batch in its own thread)
    and stepped through the same call (``simulate.direct_step``). Pushes are applied at the same steps,
    and a prop with per-step logic (the ball's release, grip and hand-over: ``Prop.step``) runs it as in
    the evaluation, so the replay is the evaluation's physics: ``replay_max_divergence_m`` is how far the
    replayed CoM strays from the closed-loop one (0 when the replay is bit for bit; open loop, any
    difference would grow). The old floor - a zero-torque collapse from the settled state, a different
    contact load - is kept as ``zero_torque_s_per_clip`` for reference;
(b) the batched evaluator: N candidates in lockstep with the compiled controller;
(c) per-candidate serial evaluation (one clip after another, one thread);
(d) one full generation of N candidates with each optimizer backend;
(e) the same N candidates scored robustly: each on the task's ensemble (``cmrt.motion.ensemble``),
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
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import mujoco
import mujoco.batch
import numpy as np

from cmrt.body.character import character
from cmrt.body.props import Prop, prop_class
from cmrt.control import ControllerConfig
from cmrt.errors import CmrtError
from cmrt.modes import BACKENDS
from cmrt.motion.curve import Cmrt
from cmrt.motion.ensemble import training_members
from cmrt.motion.library import library_curve
from cmrt.motion.task import Task
from cmrt.optimize.parallel import Evaluator, evaluate_batch, evaluate_candidate
from cmrt.sim.clip3d import clip_3d
from cmrt.sim.simulate import direct_step, settled_state, simulate_batch, thread_count
from cmrt.sim.spatial import replay_3d

# (evaluations, wall seconds) of one full optimization of a task: supplied by the caller (the CLI runs
# ``jobs.optimize_now``; this module sits below the store and the service)
OptimizeFn = Callable[[Task], tuple[int, float]]


def bench_candidates(task: Task, n: int) -> list[np.ndarray]:
    """Small perturbations of the library optimum (most clips run to the end), or of the flat start."""
    try:
        base = library_curve(task).to_params()
    except CmrtError:
        base = np.zeros(task.n_cmrt_params)
    rng = np.random.default_rng(0)
    return [base + rng.normal(0.0, 0.02, base.size) for _ in range(n)]


@dataclass(frozen=True)
class Replay:
    """What the batched evaluator applied to a batch of clips, to be stepped again open loop (the floor)."""

    ctrl_nm: np.ndarray  # (steps, n, nu): the torques applied during each step (held between control steps)
    steps: np.ndarray  # (n,) int: steps each clip ran in the evaluation (to the end of its tail, or its fall)
    com_m: np.ndarray  # (steps, n, 2): the closed-loop CoM (x, z) at the start of each step; NaN past the end


def record_replay(task: Task, curves: list[Cmrt], config: ControllerConfig = ControllerConfig()) -> Replay:
    """Run the clips as the evaluator scores them (their lengths) and recorded (their torques at every step;
    a recorded run is the scoring run up to a fall, then plays the topple out, which is cut off here).
    Nominal clips only: the replay applies the task's own pushes, not an ensemble member's."""
    scored = simulate_batch(task, curves, config)
    recorded = simulate_batch(task, curves, config, record=True)
    steps = np.array([tr.time_s.size for tr in scored])
    nu = recorded[0].ctrl_nm.shape[1]
    ctrl = np.zeros((steps.max(), len(curves), nu))
    com = np.full((steps.max(), len(curves), 2), np.nan)
    for i, tr in enumerate(recorded):
        if tr.time_s.size < steps[i] or tr.fell != scored[i].fell:  # scores do not depend on record (tested)
            raise CmrtError(f"clip {i}: the recorded run is not the scored one")
        ctrl[: steps[i], i] = tr.ctrl_nm[: steps[i]]
        com[: steps[i], i] = tr.com_m[: steps[i]]
    return Replay(ctrl_nm=ctrl, steps=steps, com_m=com)


def replay_physics(task: Task, replay: Replay, threads: int | None = None,
                   config: ControllerConfig = ControllerConfig(), com_out: np.ndarray | None = None) -> np.ndarray:
    """Step ``replay``'s clips open loop with their recorded torques (the floor), split into groups on
    threads as ``simulate_batch`` splits a batch. ``com_out`` (steps, n, 2): filled with the replayed CoM at
    the start of each step (not while timing). Returns the steps each clip was stepped (from its clock)."""
    n = replay.steps.size
    groups = min(n, threads or thread_count(n))
    settled_state(task, config)  # cached before the threads share it, as simulate_batch does
    if groups <= 1:
        return _replay_group(task, replay, np.arange(n), config, com_out)
    bounds = np.linspace(0, n, groups + 1).round().astype(int)
    parts = [np.arange(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    with ThreadPoolExecutor(max_workers=groups) as pool:
        return np.concatenate(list(pool.map(lambda rows: _replay_group(task, replay, rows, config, com_out), parts)))


def _replay_group(task: Task, replay: Replay, rows: np.ndarray, config: ControllerConfig,
                  com_out: np.ndarray | None) -> np.ndarray:
    """One group of the replay on a one-thread Batch in the calling thread: per step, nothing but the
    torques (at control steps), a push where it changes, the prop's own per-step logic (if it has any)
    and the step."""
    m = task.model()
    n = rows.size
    dt = m.opt.timestep
    steps = replay.steps[rows]
    ctrl = np.ascontiguousarray(replay.ctrl_nm[:, rows])
    times = np.arange(steps.max()) * dt
    push = task.pushes_n(times)
    push_steps = set(np.flatnonzero(np.concatenate([[True], np.diff(push) != 0])).tolist())
    thorax = character().thorax_body
    vel_stage = mujoco.mjtStage.mjSTAGE_VEL

    batch = mujoco.batch.Batch(m, nsim=n, nthread=1, persistent=True)
    prop = prop_class(task.prop)(m, task.params)
    state = settled_state(task, config)
    b = {k: batch.bind(k) for k in {"ctrl", "xfrc_applied", "time", "subtree_com", "xpos", *state} | prop.fields()}
    for k, v in state.items():
        b[k][:] = v
    b["time"][:] = 0.0
    prop.start(batch, b, n, task.end_qpos())
    batch.forward(stage=vel_stage)
    prop_steps = type(prop).step is not Prop.step  # the ball: released, gripped and handed over mid-clip
    every, every_step = config.control_every, prop.every_step
    step_rows, rows32, ids, sel = direct_step(batch, vel_stage), None, np.arange(n), slice(None)
    next_end = steps.min()
    ctrl_b, push_b = b["ctrl"], b["xfrc_applied"]
    for k in range(steps.max()):
        if k >= next_end:  # clips whose evaluation ended (the tail, or a fall) are not stepped again
            ids = sel = np.flatnonzero(steps > k)
            rows32 = ids.astype(np.int32)
            next_end = steps[ids].min()
        control = k % every == 0
        if control:
            if rows32 is None:
                np.copyto(ctrl_b, ctrl[k])
            else:
                ctrl_b[ids] = ctrl[k, ids]
        if prop_steps and (control or every_step):
            prop.step(batch, b, ids, times[k])
        if k in push_steps:
            push_b[sel, thorax, 0] = push[k]
        if com_out is not None:
            com_out[k, rows[ids]] = b["subtree_com"][ids, 1][:, [0, 2]]
        step_rows(rows32)
    return np.rint(b["time"] / dt).astype(int)


def _timed(fn) -> float:
    """The wall time of ``fn()``, s."""
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def run_bench(task: Task, population: int = 16, repeat: int = 5, backends=BACKENDS, workers: int = 2,
              optimize: OptimizeFn | None = None) -> dict:
    """Time the physics floor, the batched and serial evaluators and a generation on each backend, in
    alternating rounds (ratios within a round: this VM's speed drifts); what ``cmrt bench`` prints.
    ``optimize``: also time one full optimization of ``task`` against its evaluations x floor. A 3D task's
    clips are timed by ``_clips_3d``'s rules."""
    m = task.model()  # the humanoid and the task's prop
    tail_s = task.tail_s if task.body == "planar" else 0.0  # a 3D clip has no tail: it ends with its clip
    n_steps = int(round((task.clip_s + tail_s) / m.opt.timestep))  # what an evaluation simulates
    xs = bench_candidates(task, population)
    robust = task.with_robust()
    members = training_members(robust, robust.robust, prop_class(task.prop).mass_body is not None)
    clips = _clips_3d(task, xs, robust) if task.body != "planar" else _clips_planar(task, xs, robust, members,
                                                                                    n_steps)
    rounds: dict[str, list[float]] = {k: [] for k in clips.timed}
    generations: dict[str, list[float]] = {}
    for _ in range(repeat):  # alternate so machine noise hits each figure alike
        for name, fn in clips.timed.items():
            rounds[name].append(_timed(fn))
    for b in backends:  # one backend alive at a time: idle workers/clusters would steal CPU
        with Evaluator(b, workers=workers) as ev:
            ev(task, xs[:2])  # warm-up: worker processes, clusters, per-process caches
            generations[b] = [_timed(lambda ev=ev: ev(task, xs)) for _ in range(repeat)]

    ratios = np.array(rounds["batched"]) / np.array(rounds["physics"])
    per = {k: float(np.median(v)) / population for k, v in rounds.items()}
    out = {
        "task": task.name, "speed": task.speed, "population": population, "steps_per_clip": n_steps,
        "control_hz": 1.0 / (m.opt.timestep * ControllerConfig().control_every),
        "candidates_that_fell": clips.fell,
        "physics_only_s_per_clip": per["physics"],  # the floor: the clips' own torques replayed (a)
        "floor": clips.floor,
        "steps_evaluated": clips.steps_evaluated, "steps_replayed": clips.steps_replayed,
        "replay_max_divergence_m": clips.divergence_m,
        "zero_torque_s_per_clip": per.get("zero_torque"),  # the old floor: a zero-torque collapse, all steps
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
        "machine": f"{platform.machine()}, {os.cpu_count() or 1} cores, mujoco {mujoco.__version__}",
        "repeat": repeat,
    }
    if optimize is not None:
        out.update(_time_optimize(task, optimize, out["physics_only_s_per_clip"]))
    return out


@dataclass(frozen=True)
class _Clips:
    """What ``run_bench`` times for a task's candidates (each a callable, timed in alternating rounds: "physics"
    the floor, "batched" and "serial" the evaluators, "robust" the ensemble, optionally "zero_torque") and what it
    says of them."""

    timed: dict[str, Callable[[], object]]
    floor: str
    fell: int
    steps_evaluated: int
    steps_replayed: int
    divergence_m: float


def _clips_planar(task: Task, xs: list[np.ndarray], robust: Task, members: list, n_steps: int) -> _Clips:
    """The planar body's: the lockstep batch on every core, its floor the same clips replayed on
    ``mujoco.batch`` the same way (``replay_physics``)."""
    m, threads = task.model(), os.cpu_count() or 1
    population = len(xs)
    curves = [Cmrt.from_params(x, task.clip_s) for x in xs]
    state = settled_state(task, ControllerConfig())
    replay = record_replay(task, curves)  # also the warm-up: settled state, compiled controller
    replayed_com = np.full_like(replay.com_m, np.nan)
    steps_replayed = replay_physics(task, replay, com_out=replayed_com)
    with np.errstate(invalid="ignore"):
        divergence = np.hypot(*(replayed_com - replay.com_m).transpose(2, 0, 1))

    def zero_torque() -> None:
        batch = mujoco.batch.Batch(m, nsim=population, nthread=threads, persistent=True)
        for k, v in state.items():
            batch.bind(k)[:] = v
        batch.forward()
        for _ in range(n_steps):
            batch.step()

    ensemble_curves = [c for c in curves for _ in members]
    timed = {"physics": lambda: replay_physics(task, replay), "zero_torque": zero_torque,
             "batched": lambda: simulate_batch(task, curves),
             "serial": lambda: [evaluate_candidate(task, x) for x in xs],
             "robust": lambda: simulate_batch(robust, ensemble_curves, perturbations=members * population)}
    return _Clips(timed, "the evaluated clips' recorded torques replayed open loop, as many steps as each ran",
                  int(sum(tr.fell for tr in simulate_batch(task, curves))), int(replay.steps.sum()),
                  int(steps_replayed.sum()), float(np.nanmax(divergence)))


def _clips_3d(task: Task, xs: list[np.ndarray], robust: Task) -> _Clips:
    """The 3D body's: its clips run one after another in one thread (``cmrt.sim.clip3d``; no lockstep batch yet),
    so "batched" is the in-process evaluator a generation's chunk runs on (``evaluate_batch``), "serial" one
    candidate at a time, and the floor each clip's recorded torques, push and prop replayed open loop on its own
    model in the same thread (``replay_3d``) - per CPU, like for like."""
    clips = [clip_3d(task, Cmrt.from_params(x, task.clip_s)) for x in xs]  # also the warm-up
    results = [c.result for c in clips]
    divergence, steps = 0.0, 0
    for r in results:
        com = np.full_like(r.com_m, np.nan)
        steps += replay_3d(r, com_out=com)
        divergence = max(divergence, float(np.linalg.norm(com - r.com_m, axis=1).max()))
    evaluated = sum(int(round(r.inputs.clip_s / task.model().opt.timestep)) for r in results)
    timed = {"physics": lambda: [replay_3d(r) for r in results], "batched": lambda: evaluate_batch(task, xs),
             "serial": lambda: [evaluate_candidate(task, x) for x in xs], "robust": lambda: evaluate_batch(robust, xs)}
    return _Clips(timed, "the evaluated 3D clips' recorded torques, push and prop replayed open loop, one after "
                  "another in one thread", sum(c.fell for c in clips), evaluated, steps, divergence)


def _time_optimize(task: Task, optimize: OptimizeFn, floor_s_per_clip: float) -> dict:
    """One full optimization of ``task``, timed against its evaluations x the physics floor per clip."""
    evaluations, wall_s = optimize(task)
    floor_s = evaluations * floor_s_per_clip
    return {"optimize_evaluations": evaluations, "optimize_wall_s": wall_s, "optimize_floor_s": floor_s,
            "ratio_optimize_to_floor": wall_s / floor_s if floor_s > 0 else float("nan")}
