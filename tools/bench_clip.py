"""Cost of one clip evaluation vs. stepping the same clip's physics alone.

Measured in one process, one run (machines here are noisy; compare the ratio):

* evaluation: ``simulate`` + ``evaluate`` of the fast bend (zero CMRT, library CMRT);
* physics only: the same number of ``mj_step`` calls from the same settled state,
  (a) with zero control, (b) replaying the controller's recorded torques open loop.

    python tools/bench_clip.py [--task bend] [--speed 0.4] [--repeat 5] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import mujoco
import numpy as np

from cmrt import ControllerConfig, evaluate, library_curve, load_task, simulate
from cmrt.character import character
from cmrt.simulate import settled_state


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description="clip evaluation cost vs physics-only stepping")
    ap.add_argument("--task", default="bend")
    ap.add_argument("--speed", type=float, default=0.4)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    task = load_task(args.task).with_speed(args.speed)
    m = character().model
    n_steps = int(round(task.clip_s / m.opt.timestep))
    state = settled_state(task, ControllerConfig())
    curve = library_curve(task)
    traj = simulate(task, curve)
    ctrl_seq = traj.ctrl_nm

    def physics(replay: bool):
        d = mujoco.MjData(m)
        mujoco.mj_setState(m, d, state, mujoco.mjtState.mjSTATE_INTEGRATION)
        for k in range(n_steps):
            if replay:
                d.ctrl[:] = ctrl_seq[min(k, len(ctrl_seq) - 1)]
            mujoco.mj_step(m, d)

    res = {
        "task": task.name,
        "speed": task.speed,
        "steps_per_clip": n_steps,
        "eval_zero_cmrt_s": best_of(lambda: evaluate(task, simulate(task)), args.repeat),
        "eval_library_cmrt_s": best_of(lambda: evaluate(task, simulate(task, curve)), args.repeat),
        "physics_zero_control_s": best_of(lambda: physics(False), args.repeat),
        "physics_replayed_torques_s": best_of(lambda: physics(True), args.repeat),
        "machine": f"{platform.machine()} x{os.cpu_count()} mujoco {mujoco.__version__}",
    }
    res["ratio_eval_to_physics"] = res["eval_library_cmrt_s"] / res["physics_replayed_torques_s"]
    res["us_per_control_step"] = 1e6 * (res["eval_library_cmrt_s"] - res["physics_replayed_torques_s"]) / n_steps
    if args.json:
        print(json.dumps(res, indent=2))
    else:
        for k, v in res.items():
            print(f"{k:28s} {v:.4f}" if isinstance(v, float) else f"{k:28s} {v}")


if __name__ == "__main__":
    np.set_printoptions(precision=4)
    main()
