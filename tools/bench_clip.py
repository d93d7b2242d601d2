"""One clip, one process: the cost of evaluating a fast-bend clip vs stepping its physics alone.

(a) ``simulate`` + ``evaluate`` of one clip (library CMRT), one MuJoCo thread;
(b) the same number of ``mj_step`` calls from the same settled state on one ``MjData``,
    zero control. Best of ``--repeat``, alternating, in one run. ``cmrt bench`` measures
    the batched evaluator against the batched physics floor.

    python tools/bench_clip.py [--task bend] [--speed 0.4] [--repeat 5] [--json]
"""

from __future__ import annotations

import argparse
import json
import time

import mujoco

from cmrt import ControllerConfig, evaluate, library_curve, load_task, simulate
from cmrt.sim.simulate import settled_state


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", default="bend")
    ap.add_argument("--speed", type=float, default=0.4)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    task = load_task(args.task).with_speed(args.speed)
    m = task.model()
    n_steps = int(round((task.clip_s + task.tail_s) / m.opt.timestep))  # what an evaluation simulates
    state = settled_state(task, ControllerConfig())
    curve = library_curve(task)

    def physics() -> None:
        d = mujoco.MjData(m)
        for k, v in state.items():
            getattr(d, k)[:] = v
        for _ in range(n_steps):
            mujoco.mj_step(m, d)

    def clip() -> None:
        evaluate(task, simulate(task, curve, record=False))

    best = {"clip": float("inf"), "physics": float("inf")}
    clip()
    for _ in range(args.repeat):
        for name, fn in (("clip", clip), ("physics", physics)):
            t0 = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - t0)
    out = {"task": task.name, "speed": task.speed, "steps": n_steps, "eval_s_per_clip": best["clip"],
           "physics_only_s_per_clip": best["physics"], "ratio": best["clip"] / best["physics"]}
    print(json.dumps(out) if args.json else "\n".join(f"{k:24s} {v}" for k, v in out.items()))


if __name__ == "__main__":
    main()
