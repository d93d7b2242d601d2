"""A fingerprint of every trajectory array of a fixed set of clips: compare it before and after a refactor.

    python tools/bit_identity.py [--quick] --out before.json        # on the old code
    python tools/bit_identity.py [--quick] --out after.json         # on the new code
    python tools/bit_identity.py --compare before.json after.json   # exit 1 and the differing arrays

The set: every shipped planar task (bend at 0.4 and 1.2 s, rise, punch, catch, push, push-recovery with its
stepping) with the zero and the library CMRT, recorded (``simulate(..., record=True)``: every array at
every step, falls played out in protective mode) and scored (``record=False``, the optimizer's path), the
robust ensemble of the fast bend and the catch as one batch, Yu's reference mode on the fast bend, and one
sequence (``four-poses``). Each array is hashed with its dtype and shape (SHA-256 of its bytes), each
scalar written out, so "identical" means bit for bit on this machine. ``--quick``: the fast bend and the
catch only. ``--body3d``: the 3D body's set instead - every shipped 3D task with the zero and the library CMRT,
and the standing body pushed from the side (each clip's samples, torques, figures, verdict and objective). A
refactor that changes no physics must leave the file unchanged; compare on one machine (another machine's libm
or BLAS may round differently).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys

import numpy as np


def _digest(value) -> object:
    if isinstance(value, np.ndarray):
        data = np.ascontiguousarray(value)
        return f"{data.dtype.str}{list(data.shape)}:{hashlib.sha256(data.tobytes()).hexdigest()[:32]}"
    if isinstance(value, float | int | bool | str) or value is None:
        return value
    return repr(value)


def fingerprint(traj) -> dict:
    """Every field of a Trajectory: arrays hashed, scalars as they are."""
    return {f.name: _digest(getattr(traj, f.name)) for f in dataclasses.fields(traj)}


def clips(quick: bool):
    """(name, list of Trajectory) for the fixed set."""
    from cmrt import library_curve, load_sequence, load_task, simulate, superpose
    from cmrt.body.props import prop_class
    from cmrt.motion.ensemble import training_members
    from cmrt.sim.simulate import simulate_batch

    tasks = [("bend-0.4", load_task("bend").with_speed(0.4)), ("catch", load_task("catch"))]
    if not quick:
        tasks += [("bend-1.2", load_task("bend").with_speed(1.2)), ("rise", load_task("rise")),
                  ("punch", load_task("punch")), ("push", load_task("push")),
                  ("push-recovery", load_task("push-recovery"))]
    for name, task in tasks:
        try:
            library = library_curve(task)
        except Exception:  # a task without a library entry (push-recovery steps instead)
            library = None
        curves = [None] if library is None else [None, library]
        for record in (True, False):
            yield f"{name}/{'recorded' if record else 'scored'}", simulate_batch(task, curves, record=record)
    for name in ("bend-0.4", "catch"):
        task = dict(tasks)[name]
        members = training_members(task.with_robust(True), task.with_robust(True).robust,
                                   prop_class(task.prop).mass_body is not None)
        yield f"{name}/robust-ensemble", simulate_batch(task, [library_curve(task)] * len(members),
                                                         record=False, perturbations=members)
    yield "bend-0.4/yu", simulate_batch(dict(tasks)["bend-0.4"].with_reference("yu"), [None], record=True)
    if not quick:
        seq = load_sequence("four-poses")
        yield "sequence/four-poses", [simulate(seq, superpose(seq), record=True)]


def clips_3d():
    """(name, list of 3D clips' records) for the 3D set."""
    from cmrt import available_tasks, library_curve, load_task, simulate

    names = [n for n in available_tasks() if getattr(load_task(n), "body", "planar") != "planar"]
    for name in sorted(names):
        task = load_task(name)
        yield name, [_clip_3d(simulate(task, curve)) for curve in (None, library_curve(task))]
    stand = load_task("docs/examples/stand3d.toml")
    yield "stand3d/side-100", [_clip_3d(simulate(stand.with_params(push_force_y_n=100.0)))]


def _clip_3d(clip) -> dict:
    """A 3D clip's record: its samples and figures (``StandResult``) and its score."""
    record = {f"result.{k}": v for k, v in fingerprint(clip.result).items() if k != "inputs"}  # objects, no values
    return {**record, "objective": clip.objective, "failed_rules": list(clip.failed_rules)}


def _flat(doc: dict) -> dict:
    return {f"{clip}[{i}].{k}": v for clip, trajs in doc.items() for i, t in enumerate(trajs) for k, v in t.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="write the fingerprint here (default: stdout)")
    ap.add_argument("--quick", action="store_true", help="the fast bend and the catch only")
    ap.add_argument("--body3d", action="store_true", help="the 3D body's clips instead")
    ap.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"))
    a = ap.parse_args(argv)
    if a.compare:
        before, after = (_flat(json.loads(open(p).read())) for p in a.compare)
        diff = sorted(k for k in set(before) | set(after) if before.get(k, "<absent>") != after.get(k, "<absent>"))
        print(json.dumps({"identical": not diff, "values": len(before), "differences": diff[:200]}, indent=1))
        return 0 if not diff else 1
    if a.body3d:
        out = dict(clips_3d())
    else:
        out = {name: [fingerprint(t) for t in trajs] for name, trajs in clips(a.quick)}
    text = json.dumps(out, indent=1, sort_keys=True)
    if a.out:
        with open(a.out, "w") as fh:
            fh.write(text + "\n")
        print(f"wrote {a.out}: {len(out)} clip sets, {sum(len(v) for v in out.values())} trajectories")
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
