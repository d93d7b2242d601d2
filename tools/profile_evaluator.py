"""Split the batched evaluator's wall time into MuJoCo stepping, the compiled control step and the rest.

Alternates, in one process, the physics floor (``cmrt bench``'s: the same clips' recorded torques replayed
open loop, as many steps as each was evaluated, ``bench.replay_physics``) with ``simulate_batch`` of N
candidates, both on ONE thread (one ``Batch`` thread; one group of clips), timing the physics steps
(``Batch.step``, or the scoring loop's direct step, ``simulate.direct_step``) and
``cmrt.sim.tick.control_tick`` (the controller kernel, the monitor and the records of a control step) inside
the latter; "rest" is the evaluator's own Python (the loop, CoP samples, setup). On one thread the parts
add up to the wall time; the default evaluator runs one such group per core in parallel threads, and
the last column is that: its wall time against the floor on all cores' threads (``cmrt bench``'s ratio).
docs/performance.md has the figures. Timers wrap the calls, so the split costs a few percent itself.

A 3D task's clips run one after another in one thread, a clip without a prop whole in compiled code
(``cmrt.sim.spatial_loop.run_clip``: MuJoCo's steps, the control steps, the samples and the fall monitor): its
floor is ``cmrt bench``'s (``replay_3d`` of each evaluated clip), its evaluator ``evaluate_batch``, split into the
compiled clips and the Python around them (the targets made, the controller set up, the clip scored); the
compiled clips' physics is the floor's, so their control steps are what they take beyond it. A task with a prop
runs its Python loop, and its split is all "Python".

    python tools/profile_evaluator.py [--task bend] [--speed 0.4] [--population 16] [--rounds 5]
    python tools/profile_evaluator.py --task leg-lift --speed 2.3 --population 8 --rounds 3
"""

from __future__ import annotations

import argparse
import os
import time

import mujoco
import mujoco.batch
import numpy as np

from cmrt import Cmrt, load_task
from cmrt.optimize.bench import bench_candidates, record_replay, replay_physics
from cmrt.optimize.parallel import evaluate_batch
from cmrt.sim import simulate as simulate_module  # noqa: E402
from cmrt.sim import spatial_loop
from cmrt.sim.clip3d import clip_3d
from cmrt.sim.simulate import simulate_batch
from cmrt.sim.spatial import replay_3d


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="bend")
    p.add_argument("--speed", type=float, default=0.4)
    p.add_argument("--population", type=int, default=16)
    p.add_argument("--rounds", type=int, default=5)
    args = p.parse_args()
    task = load_task(args.task).with_speed(args.speed)
    if task.body != "planar":
        profile_3d(task, args.population, args.rounds)
        return
    n = args.population
    curves = [Cmrt.from_params(x, task.clip_s) for x in bench_candidates(task, n)]
    replay = record_replay(task, curves)  # also the warm-up: compiled code, settled state
    spent = {"step": 0.0, "tick": 0.0}
    step, control_tick = mujoco.batch.Batch.step, simulate_module.control_tick
    direct_step = simulate_module.direct_step

    def timed_step(self, *a, **k):  # the Python path's steps
        t0 = time.perf_counter()
        step(self, *a, **k)
        spent["step"] += time.perf_counter() - t0

    def timed_direct_step(batch, stage):  # the scoring loop's steps (simulate.direct_step)
        inner = direct_step(batch, stage)

        def timed(rows):
            t0 = time.perf_counter()
            inner(rows)
            spent["step"] += time.perf_counter() - t0

        return timed

    def timed_tick(*a):
        t0 = time.perf_counter()
        out = control_tick(*a)
        spent["tick"] += time.perf_counter() - t0
        return out

    def floor(threads: int) -> float:  # groups of one-thread batches, as the evaluator runs
        t0 = time.perf_counter()
        replay_physics(task, replay, threads=threads)
        return time.perf_counter() - t0

    def wall(fn) -> float:
        t0 = time.perf_counter()
        fn()
        return time.perf_counter() - t0

    cores = os.cpu_count() or 1
    rows = []
    for _ in range(args.rounds):
        f1 = floor(1)
        mujoco.batch.Batch.step, simulate_module.control_tick = timed_step, timed_tick
        simulate_module.direct_step = timed_direct_step
        spent.update(step=0.0, tick=0.0)
        try:
            w1 = wall(lambda: simulate_batch(task, curves, threads=1))
        finally:
            mujoco.batch.Batch.step, simulate_module.control_tick = step, control_tick
            simulate_module.direct_step = direct_step
        fc = floor(cores)
        wc = wall(lambda: simulate_batch(task, curves))
        rows.append((f1, w1, spent["step"], spent["tick"], w1 - spent["step"] - spent["tick"], fc, wc))
        ms = [1e3 * x / n for x in rows[-1]]
        print(f"one thread: floor {ms[0]:.1f} | evaluator {ms[1]:.1f} = steps {ms[2]:.1f} + control steps "
              f"{ms[3]:.1f} + rest {ms[4]:.1f} ms/clip (x{w1 / f1:.2f}) | {cores} threads: floor {ms[5]:.1f}, "
              f"evaluator {ms[6]:.1f} ms/clip (x{wc / fc:.2f})")
    a = np.array(rows)
    share = np.median(a[:, 2:5] / a[:, :1], axis=0)
    print(f"median, one thread: x{np.median(a[:, 1] / a[:, 0]):.2f} = steps {share[0]:.2f} + control steps "
          f"{share[1]:.2f} + rest {share[2]:.2f} of the floor; {cores} threads: x{np.median(a[:, 6] / a[:, 5]):.2f} "
          f"(load {os.getloadavg()[0]:.2f})")


def profile_3d(task, n: int, rounds: int) -> None:
    """The 3D body's split (the module's docstring), one line a round and the median."""
    xs = bench_candidates(task, n)
    results = [clip_3d(task, Cmrt.from_params(x, task.clip_s)).result for x in xs]  # also the warm-up
    spent = [0.0]
    run_clip = spatial_loop.run_clip

    def timed_run(*a):
        t0 = time.perf_counter()
        out = run_clip(*a)
        spent[0] += time.perf_counter() - t0
        return out

    rows = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        for r in results:
            replay_3d(r)
        floor = time.perf_counter() - t0
        spent[0] = 0.0
        spatial_loop.run_clip = timed_run
        try:
            t0 = time.perf_counter()
            evaluate_batch(task, xs)
            wall = time.perf_counter() - t0
        finally:
            spatial_loop.run_clip = run_clip
        rows.append((floor, wall, spent[0], wall - spent[0]))
        ms = [1e3 * v / n for v in rows[-1]]
        print(f"3D, one thread: floor {ms[0]:.1f} | evaluator {ms[1]:.1f} = compiled clips {ms[2]:.1f} + Python "
              f"{ms[3]:.1f} ms/clip (x{wall / floor:.2f}); the compiled clips' control steps ~{ms[2] - ms[0]:.1f}")
    a = np.array(rows)
    share = np.median(a[:, 1:4] / a[:, :1], axis=0)
    print(f"median: x{share[0]:.2f} = physics 1.00 + control steps {share[1] - 1.0:.2f} + Python {share[2]:.2f} of "
          f"the floor (load {os.getloadavg()[0]:.2f})")


if __name__ == "__main__":
    main()
