"""Peak memory per simulated clip, measured, against the model the batch size is chosen by (cmrt/optimize/memory.py).

Each measurement is a fresh Python process that scores one candidate (model compiled, start pose
settled), reads its peak RSS, scores ``--clips`` candidates in one batch (``CMRT_MEMORY_SHARE=1``: no
chunking) and reads it again; the difference over the clips is the measured bytes per clip. Run for the
task at its own clip length and at each ``--clip-s``.

    python tools/bench_memory.py [--task bend] [--clips 40] [--clip-s 10,59.5] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys

CHILD = r"""
import json, resource, sys
import numpy as np
from cmrt import load_task
from cmrt.optimize.memory import clip_bytes
from cmrt.optimize.parallel import evaluate_batch
task = load_task(sys.argv[1])
if sys.argv[3] != "-":
    task = task.with_params(clip_s=float(sys.argv[3]))
n = int(sys.argv[2])
# warm up on as many threads as the measured batch uses: a second thread's malloc arena (a few MB,
# once per process) is not a per-clip cost and swamped a 12-clip measurement (0.93x on a 2-core Xeon)
evaluate_batch(task, [np.zeros(8), np.zeros(8)])
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
rng = np.random.default_rng(0)
evaluate_batch(task, [rng.normal(0.0, 0.5, 8) for _ in range(n)])
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"task": task.name, "clip_s": task.clip_s, "tail_s": task.tail_s, "clips": n,
                  "base_rss_mb": before / 1024, "peak_rss_mb": after / 1024,
                  "measured_bytes_per_clip": (after - before) * 1024 / n, "model_bytes_per_clip": clip_bytes(task)}))
"""


def measure(task: str, clips: int, clip_s: str) -> dict:
    env = {**os.environ, "CMRT_MEMORY_SHARE": "1"}  # one batch, however large
    out = subprocess.run([sys.executable, "-c", CHILD, task, str(clips), clip_s], env=env, check=True,
                         capture_output=True, text=True)
    row = json.loads(out.stdout)
    row["model_over_measured"] = row["model_bytes_per_clip"] / max(row["measured_bytes_per_clip"], 1.0)
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", default="bend")
    ap.add_argument("--clips", type=int, default=40)
    ap.add_argument("--clip-s", default="", help="extra clip lengths, comma-separated (s)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    lengths = ["-"] + [s for s in a.clip_s.split(",") if s]
    rows = [measure(a.task, a.clips, s) for s in lengths]
    if a.json:
        print(json.dumps({"machine": platform.machine(), "python": platform.python_version(), "rows": rows}))
        return 0
    print(f"{'task':8} {'clip s':>7} {'clips':>6} {'measured MB/clip':>17} {'model MB/clip':>14} "
          f"{'model/measured':>15}")
    for r in rows:
        print(f"{r['task']:8} {r['clip_s']:7.1f} {r['clips']:6d} {r['measured_bytes_per_clip'] / 2**20:17.3f} "
              f"{r['model_bytes_per_clip'] / 2**20:14.3f} {r['model_over_measured']:15.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
