"""Split the batched evaluator's wall time into MuJoCo stepping, the controller kernel and the rest.

Alternates, in one process, the physics floor (``cmrt bench``'s: the same steps, zero control,
all cores' threads) with ``simulate_batch`` of N candidates, timing ``Batch.step`` and
``kernel.control_step`` inside the latter; "rest" is the evaluator's own Python (monitor,
references, recording, the controller wrapper, per-clip setup). docs/performance.md has the
figures. Timers wrap the two calls, so the split costs a few percent itself.

    python tools/profile_evaluator.py [--task bend] [--speed 0.4] [--population 16] [--rounds 5]
"""

from __future__ import annotations

import argparse
import os
import time

import mujoco
import mujoco.batch
import numpy as np

from cmrt import ControllerConfig, load_task
from cmrt.bench import _candidates
from cmrt.control import controller, kernel
from cmrt.curve import Cmrt
from cmrt.simulate import settled_state, simulate_batch


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", default="bend")
    p.add_argument("--speed", type=float, default=0.4)
    p.add_argument("--population", type=int, default=16)
    p.add_argument("--rounds", type=int, default=5)
    args = p.parse_args()
    task = load_task(args.task).with_speed(args.speed)
    m, n = task.model(), args.population
    n_steps = int(round((task.clip_s + task.tail_s) / m.opt.timestep))
    curves = [Cmrt.from_params(x, task.clip_s) for x in _candidates(task, n)]
    state = settled_state(task, ControllerConfig())
    spent = {"step": 0.0, "kernel": 0.0}
    step, control_step = mujoco.batch.Batch.step, kernel.control_step

    def timed_step(self, *a, **k):
        t0 = time.perf_counter()
        step(self, *a, **k)
        spent["step"] += time.perf_counter() - t0

    def timed_kernel(*a):
        t0 = time.perf_counter()
        control_step(*a)
        spent["kernel"] += time.perf_counter() - t0

    def floor() -> None:
        batch = mujoco.batch.Batch(m, nsim=n, nthread=os.cpu_count() or 1, persistent=True)
        for k, v in state.items():
            batch.bind(k)[:] = v
        batch.forward()
        for _ in range(n_steps):
            step(batch)

    mujoco.batch.Batch.step = timed_step
    controller.kernel.control_step = timed_kernel  # the module object controller.py calls through
    try:
        simulate_batch(task, curves[:2])  # warm-up: compiled code, settled state
        rows = []
        for _ in range(args.rounds):
            t0 = time.perf_counter()
            floor()
            f = time.perf_counter() - t0
            spent.update(step=0.0, kernel=0.0)
            t0 = time.perf_counter()
            simulate_batch(task, curves)
            w = time.perf_counter() - t0
            rows.append((f, w, spent["step"], spent["kernel"], w - spent["step"] - spent["kernel"]))
            ms = [1e3 * x / n for x in rows[-1]]
            print(f"floor {ms[0]:.1f} | batched {ms[1]:.1f} = steps {ms[2]:.1f} + kernel {ms[3]:.1f} + rest "
                  f"{ms[4]:.1f} ms/clip | ratio {w / f:.2f}")
    finally:
        mujoco.batch.Batch.step = step
        controller.kernel.control_step = control_step
    a = np.array(rows)
    share = np.median(a[:, 2:] / a[:, :1], axis=0)
    print(f"median ratio {np.median(a[:, 1] / a[:, 0]):.2f}; per floor: steps {share[0]:.2f}, kernel {share[1]:.2f}, "
          f"rest {share[2]:.2f} (load {os.getloadavg()[0]:.2f})")


if __name__ == "__main__":
    main()
