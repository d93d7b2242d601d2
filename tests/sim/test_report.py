"""simulate_report / sequence_report: one clip simulated and scored as JSON-safe values, a trace on request."""

import json
import math

import numpy as np

from cmrt.motion.curve import Cmrt
from cmrt.motion.sequence import load_sequence
from cmrt.motion.taskfile import load_task
from cmrt.sim.objective import evaluate
from cmrt.sim.report import evaluation_dict, sequence_report, simulate_report
from cmrt.sim.simulate import simulate


def test_the_report_is_the_evaluation_as_json_and_the_trace_is_the_trajectory(tmp_path):
    task = load_task("bend").with_speed(0.4)
    curve = Cmrt.zero(task.clip_s)
    trace = tmp_path / "t.npz"
    r = simulate_report(task, curve, "zero", str(trace))
    ev = evaluate(task, simulate(task, curve))
    assert r["objective"] == ev.objective and r["fell"] == ev.fell and r["curve"] == "zero"
    assert r["cmrt"] == curve.to_dict() and r["speed"] == 0.4
    # the fast bend lags beyond its timing bound with no CMRT, and that is why it is not a success
    assert r["timing_lag_s"] > r["timing_lag_bound_s"] and r["timing_lag_enforced"] is True
    assert r["success"] is False and "on_time" in r["failed_rules"] and r["success_rule"].startswith("pose change")
    assert r["verdict_bounds"]["max_plan_cop_error_m"] == 0.005
    json.dumps(r, allow_nan=False)  # no NaN, no Infinity
    traj = simulate(task, curve)
    with np.load(trace) as z:
        assert len(z["dof_names"]) == z["qvel"].shape[1] == task.model().nv
        np.testing.assert_array_equal(z["cop_x_m"], traj.cop_x_m)  # NaN where the feet carry nothing
        np.testing.assert_array_equal(z["time_s"], traj.time_s)


def test_non_finite_values_become_null():
    ev = evaluate(load_task("bend").with_speed(0.4), simulate(load_task("bend").with_speed(0.4)))
    d = evaluation_dict(ev)
    assert all(v is None or not isinstance(v, float) or math.isfinite(v) for v in d.values())


def test_a_sequence_report_names_its_motions():
    seq = load_sequence("four-poses")
    r = sequence_report(seq, Cmrt.zero(seq.clip_s), "zero")
    assert r["sequence"] == seq.name and len(r["motions"]) == len(seq.motions) and r["clip_s"] == seq.clip_s
