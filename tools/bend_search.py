"""Which fast bends need anticipation? Random end poses and timings of the bend, checked two ways.

    python tools/bend_search.py [--speed 0.4] [--samples 300] [--seed 1] [--commit K] [--min-force-bw F]
                                [--feasible-only] [--json]

Each sample is the shipped bend task with a random end pose (lumbar 0-45, hip -110 to -40, knee 0-90,
neck -20 to 10, shoulders -150 to 40 deg; the ankle solved for balance, as always) and random easing
windows for the trunk (hip, lumbar, neck), the legs (knee, ankle) and the arms (shoulder): start in
[0, 0.3] and end in [0.7, 1] of T. For every sample:

* the inverse-dynamics check of ``tools/analyze_reference.py`` (the reference's minimum vertical ground
  force, its CoP excess beyond the QP's band) and ``cmrt check``'s verdict (``cmrt.check_reference``: feasible -
  CoP in the feet, torques within their limits, friction, >= 0.25 BW - with the best ankle path; whether it needs
  one that starts before a 0.1 s reaction; its first violation);
* if its joints stay at or below 25 rad/s, the zero CMRT simulated on the shipped controller
  (``cmrt.simulate``, recorded, ``cmrt.sim.objective.evaluate``): success, fall and direction, tracking error
  against its bound, timing lag, planned-vs-executed CoP gap.

``--commit K`` multiplies the tracking weight W of the bend's driving joints (lumbar, hip, knee, neck,
shoulders; not the ankle, which balances) by K: a controller committed to doing the motion on time, as a
person asked to bend fast does, instead of one that keeps its CoM by slowing the motion (the shipped
controller's momentum objectives outweigh tracking ~500:1 per unit). ``--min-force-bw F`` simulates only
references whose minimum vertical ground force is at least F body weights; ``--feasible-only`` only those
``cmrt check`` finds feasible (the physically possible ones).

The summary bins the samples by the reference's minimum vertical force (body weights) and counts the
zero-CMRT failures and falls per bin: a bend that needs anticipation (fails without a CMRT) but does not
ask the ground to nearly let go would show as a failure in a bin of positive force.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import analyze_reference  # noqa: E402  (a sibling tool)

from cmrt import (  # noqa: E402
    CmrtError,
    ControllerConfig,
    check_reference,
    evaluate,
    evaluation_dict,
    simulate,
)
from cmrt.motion.taskfile import TASKS_DIR, task_from_dict  # noqa: E402

POSE_DEG = {"lumbar": (0, 45), "hip": (-110, -40), "knee": (0, 90), "neck": (-20, 10), "shoulder": (-150, 40)}
GROUPS = {"trunk": ("hip", "lumbar", "neck"), "legs": ("knee", "ankle"), "arms": ("shoulder",)}
MAX_JOINT_SPEED = 25.0  # rad/s: human range
BINS_BW = (-np.inf, -1.0, -0.5, -0.25, 0.0, 0.15, 0.3, 0.45, np.inf)
SIM_KEYS = ("success", "fell", "fall_direction", "tracking_error_rad", "tracking_bound_rad", "timing_lag_s",
            "max_plan_cop_error_m", "peak_normal_force_bw", "airborne_s", "max_joint_speed_rad_s", "objective")


DRIVING = ("lumbar", "hip", "knee", "neck", "shoulder")  # the bend's driving joints (not the balancing ankle)


@dataclasses.dataclass(frozen=True)
class CommittedConfig(ControllerConfig):
    """The shipped controller with the driving joints' tracking weight W multiplied by ``commit``."""

    commit: float = 1.0

    def tracking_weights(self, ch, walking=False):
        w = super().tracking_weights(ch, walking)
        for i, name in enumerate(ch.dof_names):
            if name.split("_")[0] in DRIVING:
                w[i] *= self.commit
        return w


def draw(rng: np.random.Generator) -> tuple[dict, dict]:
    """A random end pose (whole degrees) and timing (windows per joint group, fractions of T)."""
    end = {k: int(rng.uniform(*r)) for k, r in POSE_DEG.items()}
    timing = {}
    for joints in GROUPS.values():
        window = [round(float(rng.uniform(0.0, 0.3)), 2), round(float(rng.uniform(0.7, 1.0)), 2)]
        timing.update({j: window for j in joints})
    return end, timing


def bend_task(end: dict, timing: dict, speed: float):
    raw = tomllib.loads((TASKS_DIR / "bend.toml").read_text())
    raw = copy.deepcopy(raw)
    raw["end_pose_deg"], raw["timing"] = end, timing
    return task_from_dict(raw, "bend_search", "bend").with_speed(speed)


def check(end: dict, timing: dict, speed: float, commit: float = 1.0, min_force_bw: float = -np.inf,
          feasible_only: bool = False) -> dict | None:
    """The reference checks and, for human-speed references, the zero-CMRT run. None: pose not possible."""
    try:
        task = bend_task(end, timing, speed)
        ref = analyze_reference.analyze(task)
        verdict = check_reference(task)
    except CmrtError:
        return None  # e.g. a pose the ankle cannot balance, or outside the joint ranges
    row = {"end_pose_deg": end, "timing": timing, "ref_min_vertical_force_bw": ref["min_vertical_force_bw"],
           "ref_max_joint_speed_rad_s": ref["max_joint_speed_rad_s"], "ref_cop_excess_m": ref["cop_excess_m"],
           "ref_com_drop_m": ref["com_drop_m"], "ref_feasible": verdict.feasible,
           "ref_needs_anticipation": verdict.needs_anticipation, "ref_first_violation": verdict.first_violation}
    if (ref["max_joint_speed_rad_s"] <= MAX_JOINT_SPEED and ref["min_vertical_force_bw"] >= min_force_bw
            and (verdict.feasible or not feasible_only)):
        config = ControllerConfig() if commit == 1.0 else CommittedConfig(commit=commit)
        ev = evaluation_dict(evaluate(task, simulate(task, None, config, record=True)))
        row.update({k: ev.get(k) for k in SIM_KEYS})
    return row


def summary(rows: list[dict]) -> list[dict]:
    out = []
    sims = [r for r in rows if "success" in r]
    for lo, hi in zip(BINS_BW[:-1], BINS_BW[1:], strict=True):
        b = [r for r in sims if lo <= r["ref_min_vertical_force_bw"] < hi]
        if not b:
            continue
        ratio = [r["tracking_error_rad"] / r["tracking_bound_rad"] for r in b if r["tracking_error_rad"] is not None]
        plan = [r["max_plan_cop_error_m"] for r in b if r["max_plan_cop_error_m"] is not None]
        out.append({"ref_min_vertical_force_bw": [float(lo), float(hi)], "n": len(b),
                    "feasible": sum(r["ref_feasible"] for r in b),
                    "needs_anticipation": sum(r["ref_needs_anticipation"] for r in b),
                    "zero_failures": sum(not r["success"] for r in b), "zero_falls": sum(bool(r["fell"]) for r in b),
                    "falls_forward": sum(r["fall_direction"] == "forward" for r in b),
                    "max_tracking_over_bound": max(ratio) if ratio else None,
                    "median_plan_cop_error_m": float(np.median(plan)) if plan else None})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="random fast bends: reference check and zero-CMRT outcome")
    ap.add_argument("--speed", type=float, default=0.4)
    ap.add_argument("--samples", type=int, default=300)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--commit", type=float, default=1.0, help="factor on the driving joints' tracking weight")
    ap.add_argument("--min-force-bw", type=float, default=-np.inf, help="simulate only references at least this")
    ap.add_argument("--feasible-only", action="store_true", help="simulate only references cmrt check finds feasible")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if args.samples < 1 or args.seed < 0 or not 0 < args.commit < 1e6:
        print("error: --samples must be >= 1, --seed >= 0 and --commit in (0, 1e6)", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    rng = np.random.default_rng(args.seed)
    rows = [r for r in (check(*draw(rng), args.speed, args.commit, args.min_force_bw, args.feasible_only)
                        for _ in range(args.samples)) if r is not None]
    result = {"speed": args.speed, "samples": args.samples, "seed": args.seed, "commit": args.commit,
              "min_force_bw": args.min_force_bw if np.isfinite(args.min_force_bw) else None,
              "feasible_only": args.feasible_only, "possible": len(rows),
              "feasible": sum(r["ref_feasible"] for r in rows),
              "simulated": sum("success" in r for r in rows), "bins": summary(rows), "rows": rows,
              "wall_s": round(time.perf_counter() - t0, 1)}
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    print(f"bend T = {args.speed} s: {args.samples} samples, {result['possible']} possible poses, "
          f"{result['feasible']} feasible (cmrt check), {result['simulated']} simulated (joints <= "
          f"{MAX_JOINT_SPEED:g} rad/s)")
    print(" reference min F_z (BW)     n  feasible (anticip.)  zero fails  falls (forward)  max tracking/bound  "
          "median plan CoP gap (m)")
    for b in result["bins"]:
        lo, hi = b["ref_min_vertical_force_bw"]
        trk = "-" if b["max_tracking_over_bound"] is None else f"{b['max_tracking_over_bound']:.2f}"
        gap = "-" if b["median_plan_cop_error_m"] is None else f"{b['median_plan_cop_error_m']:.3f}"
        print(f" [{lo:+6.2f}, {hi:+6.2f})      {b['n']:4d}  {b['feasible']:4d} ({b['needs_anticipation']:4d})      "
              f"{b['zero_failures']:4d}        {b['zero_falls']:3d} "
              f"({b['falls_forward']})          {trk:>5}               {gap}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
