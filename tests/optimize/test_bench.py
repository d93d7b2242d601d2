import json

import numpy as np
import pytest

from cmrt.cli.commands import Bench, main
from cmrt.motion.curve import Cmrt
from cmrt.motion.taskfile import load_task
from cmrt.optimize.bench import record_replay, replay_physics, run_bench
from cmrt.sim.simulate import simulate_batch
from tests.service_helpers import cmrt


@pytest.mark.slow  # times every backend, repeated
def test_bench_json_reports_every_figure():
    r = cmrt("bench", "--population", "4", "--repeat", "2", "--backends", "batch,serial", "--json", check=True)
    out = json.loads(r.stdout)
    for key in ("physics_only_s_per_clip", "batched_s_per_clip", "serial_s_per_clip", "ratio_batched_to_physics",
                "zero_torque_s_per_clip"):
        assert out[key] > 0
    assert out["steps_replayed"] == out["steps_evaluated"] <= 4 * out["steps_per_clip"]
    assert out["replay_max_divergence_m"] < 1e-9  # the floor is the evaluated clips' own physics
    assert set(out["generation_s_per_clip"]) == {"batch", "serial"}
    assert out["ratio_batched_to_physics_min"] <= out["ratio_batched_to_physics"] <= out["ratio_batched_to_physics_max"]
    assert out["steps_per_clip"] == round((2.6 + 0.5) / 0.002)  # the clip and its standing tail
    assert out["robust_members"] == 7 and out["robust_s_per_member"] > 0 and out["ratio_robust_member_to_plain"] > 0
    # the full optimization against evaluations x floor (a throwaway store: the user's is not touched)
    assert out["optimize_evaluations"] > 0 and out["optimize_wall_s"] > 0
    assert out["optimize_floor_s"] == pytest.approx(out["optimize_evaluations"] * out["physics_only_s_per_clip"])
    assert out["ratio_optimize_to_floor"] == pytest.approx(out["optimize_wall_s"] / out["optimize_floor_s"])


@pytest.mark.slow  # a cmrt process
def test_bench_bad_options():
    r = cmrt("bench", "--backends", "gpu")
    assert r.returncode == 2 and "--backends must be" in r.stderr


def test_bench_bad_options_in_process(capsys):
    """The same refusal through ``cmrt.cli.main`` in this process."""
    assert main(["bench", "--backends", "gpu"]) == 2
    assert "--backends must be" in capsys.readouterr().err


def _clips(task, n_random: int = 2):
    """The zero CMRT, a CMRT that falls and random ones from the optimizer's start distribution."""
    rng = np.random.default_rng(5)
    xs = [np.zeros(8), np.array([8.0, -8.0, 8.0, -8.0, 0, 0, 0, 0])] + [rng.normal(0, 0.5, 8) for _ in range(n_random)]
    return [Cmrt.from_params(x, task.clip_s) for x in xs]


@pytest.mark.parametrize("name", ["bend", "catch"])  # catch: the ball's release, grip and hand-over replayed
def test_floor_replays_each_clip_for_the_steps_it_was_evaluated(name):
    task = load_task(name)
    curves = _clips(task)
    scored = simulate_batch(task, curves)
    replay = record_replay(task, curves)
    assert replay.steps.tolist() == [tr.time_s.size for tr in scored]
    assert scored[1].fell and replay.steps[1] < replay.steps[0]  # a fall stops the replay there
    for threads in (1, 2):  # one group, and the evaluator's split into groups on threads
        assert replay_physics(task, replay, threads=threads).tolist() == replay.steps.tolist()


@pytest.mark.parametrize("name", [pytest.param("bend", marks=pytest.mark.slow), "catch",
                                  pytest.param("push", marks=pytest.mark.slow)])  # catch fast: props replayed
def test_replayed_torques_reproduce_the_closed_loop_trajectory(name):
    """Open loop with the recorded torques, the CoM follows the closed-loop one step for step: the floor is
    the same physics as the evaluation (the first 100 control steps to 1e-9 m; in fact every step, bit for bit)."""
    task = load_task(name)
    replay = record_replay(task, _clips(task))
    com = np.full_like(replay.com_m, np.nan)
    replay_physics(task, replay, com_out=com)
    first = 100 * 4  # physics steps of 100 control steps
    assert np.allclose(com[:first], replay.com_m[:first], rtol=0, atol=1e-9, equal_nan=True)
    ran = np.isfinite(replay.com_m)
    assert np.array_equal(np.isfinite(com), ran) and np.array_equal(com[ran], replay.com_m[ran])


def test_bench_times_a_3d_task_against_its_own_replayed_physics():
    """``cmrt bench`` on the 3D body: its clips one after another in one thread (no lockstep batch), the floor
    those clips' recorded torques, push and prop stepped again open loop - the same physics, bit for bit."""
    out = run_bench(load_task("leg-lift"), population=2, repeat=1, backends=("batch",))
    assert out["steps_per_clip"] == round(4.5 / 0.002) and out["steps_replayed"] == out["steps_evaluated"] == 2 * 2250
    assert out["replay_max_divergence_m"] == 0.0 and out["zero_torque_s_per_clip"] is None
    assert 0 < out["physics_only_s_per_clip"] < out["batched_s_per_clip"]  # the controller costs something
    assert out["robust_members"] == 7 and "3D clips" in out["floor"] and set(out["generation_s_per_clip"]) == {"batch"}
    text = Bench._text(out)  # what `cmrt bench --task leg-lift` prints: no zero-torque row on the 3D body
    assert "floor: the evaluated 3D clips'" in text and "zero-torque" not in text and "batched / floor" in text
