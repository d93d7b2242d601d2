"""Directed steps (Task.steps, ``--steps``; Wu and Zordan's footstep plans): the supervisor takes the steps asked
for, each where and when it was asked, and still steps on its own when a push asks for more."""

import dataclasses

import numpy as np
import pytest

from cmrt.body.character import character
from cmrt.motion.taskfile import resolve_task
from cmrt.sim.objective import FOOTSTEP_TOLERANCE_M, evaluate
from cmrt.sim.simulate import simulate, simulate_batch

TWO_STEPS = "R:+0.30:0.6,L:+0.60:0.6"
# The rules a clip that steps may still break (controller v0.6, docs/stepping.md): fast or pushed steps slam
# (ground_force), the CoP reaches an end of a foot at a lift-off or a landing (cop_margin), a plan's weight shift
# misses by a few mm after a push (plan). Since v0.5 a split stance is judged against the stance over the landed
# feet, not the standing pose. What these tests check is the stepping itself; each states which rules it breaks.
STEPPING_OPEN = {"ground_force", "cop_margin", "plan"}


def _stepped(e, broken: set[str]) -> bool:
    """Balance kept, every planned step landed, and the verdict broken by exactly the stepping rules ``broken``."""
    return (not e.fell and e.performed is not False and e.settled and set(e.failed_rules) == broken
            and broken <= STEPPING_OPEN)


def _heel_to_center_m() -> float:
    ch = character()
    heel, toe = (ch.model.geom_pos[g, 0] for g in ch.foot_point_geoms[:2])
    return 0.5 * (toe - heel)


def test_two_steps_forward_land_where_asked_and_the_body_comes_to_rest():
    """The issue's first must-show: two steps, each foot's centre within 2 cm of its target (measured here from
    the footprints, independently of the supervisor's own figure), balance kept, standing still after, each foot
    landing heel first (toe up by the heel strike's 0.05 rad, about 1.2 cm over the foot) slower than 0.3 m/s and
    its toe down within 0.3 s, the ground force within 2.5 body weights; a success, standing in the stance over its
    feet (0.04 rad from it; 0.62 rad from the standing pose), planted feet sliding under 1 cm."""
    task = resolve_task("stand", params={"clip_s": 4.0}, steps=TWO_STEPS)
    traj = simulate(task)
    e = evaluate(task, traj)
    assert _stepped(e, set()) and e.success, e
    assert e.final_pose_error_rad < 0.1 and e.max_touchdown_force_bw <= 2.5 and e.max_foot_slip_m <= 0.01
    assert e.steps == 2 and e.footsteps_landed == 2
    origin = traj.support_center_x_m[0]  # the start stance's centre: the plan's x = 0
    landed = {foot: heel + _heel_to_center_m() for foot, _, heel in traj.footprints}
    assert landed[0] - origin == pytest.approx(0.30, abs=0.02)
    assert landed[1] - origin == pytest.approx(0.60, abs=0.02)
    assert e.max_footstep_error_m < 0.02
    assert e.peak_normal_force_bw <= 2.5 and e.airborne_s <= 0.01 and e.max_joint_speed_rad_s <= 25.0
    dt = traj.time_s[1] - traj.time_s[0]
    landed_at = np.array([landed_s for _, landed_s, _ in traj.footprints])
    for foot, landed_s, _ in traj.footprints:
        k = int(round(landed_s / dt))
        lift = traj.point_lift_m[k - 5 : k, 2 * foot : 2 * foot + 2]
        speed = -np.diff(lift, axis=0) / dt
        assert speed.max() < 0.3  # slowly
        assert 0.005 < lift[-1, 1] - lift[-1, 0] < 0.02  # heel first: the toe still up
    flat = np.array(traj.flat_times_s)  # then the toe comes down: each foot's second contact
    assert flat.size == 2 and np.all((flat > landed_at) & (flat < landed_at + 0.3))


def test_a_step_back_lands_where_asked():
    """A step back from standing: the capture-point plan first moves the CoP forward to bring the CoM back over
    the stance foot, then the foot swings back (with the step's Bezier CoM target the swing foot took the body's
    weight and never lifted)."""
    task = resolve_task("stand", params={"clip_s": 3.0}, steps="R:-0.30:0.6")
    e = evaluate(task, simulate_batch(task, [None], record=False)[0])
    assert _stepped(e, set()) and e.footsteps_landed == 1 and e.max_footstep_error_m < 0.02


def test_a_plan_with_a_step_far_from_its_target_is_not_performed():
    """The judge: the same clip with one landing moved beyond FOOTSTEP_TOLERANCE_M is not a performed plan."""
    task = resolve_task("stand", params={"clip_s": 4.0}, steps=TWO_STEPS)
    traj = simulate_batch(task, [None], record=False)[0]
    assert evaluate(task, traj).performed
    off = dataclasses.replace(traj, footstep_errors_m=(traj.footstep_errors_m[0], FOOTSTEP_TOLERANCE_M + 0.01))
    e = evaluate(task, off)
    assert e.performed is False and not e.success and e.max_footstep_error_m > FOOTSTEP_TOLERANCE_M
    short = dataclasses.replace(traj, footstep_errors_m=traj.footstep_errors_m[:1])  # one step never landed
    assert evaluate(task, short).performed is False


def test_the_walk_task_walks_upright_and_comes_to_rest():
    """The walk: a 0.2 m step, five 0.4 m steps of 0.5 s and feet together, each where asked, at >= 0.6 m/s over its
    steady steps (a person's slow walk), the arms swinging opposite the legs; standing still at the end; the ground
    force within 2.5 body weights, never airborne; the thorax within 10 degrees of upright (``max_thorax_pitch_deg``;
    the walking pattern's trunk weights). A step's foot follows its path firmly (``StepConfig.swing_*``) and
    lands heel first on the heel pad: touchdowns within the 1.5 body weights of a person's walk, planted feet slide
    under 1 cm, each stance foot's CoP rolls over at least half of heel to toe (``GaitPattern``: the rolling anchor).
    Recorded or not, the clip is judged alike (the toe's contact after a heel strike: ``LandingWatch``)."""
    task = resolve_task("walk")
    traj = simulate(task)
    e = evaluate(task, traj)
    assert e.success and e.failed_rules == () and e.max_plan_cop_error_m <= 0.005, e
    assert e.success_rule == "footsteps: every step within 3 cm, then standing in the stance over them"
    assert e.max_foot_slip_m <= 0.01 and e.max_touchdown_force_bw <= 1.5 and e.min_stance_cop_roll >= 0.5
    landed_s = np.array([t for _, t, _ in traj.footprints])  # every step forward: its toe down after its heel
    assert np.all((np.array(traj.flat_times_s) > landed_s) & (np.array(traj.flat_times_s) < landed_s + 0.3))
    unrecorded = evaluate(task, simulate_batch(task, [None], record=False)[0])
    assert (unrecorded.success, unrecorded.max_plan_cop_error_m) == (e.success, e.max_plan_cop_error_m)
    assert e.steps == e.footsteps_landed == len(task.steps) >= 6
    assert e.max_footstep_error_m < 0.02 and e.walk_speed_m_s >= 0.6
    assert e.peak_normal_force_bw <= 2.5 and e.airborne_s == 0.0 and e.max_joint_speed_rad_s <= 25.0
    # the thorax's pitch in the world, + forward (it stands at +3.7 deg): within 10 degrees of upright, as the figure
    thorax_deg = np.degrees(traj.qpos[:, 2] + traj.qpos[:, character().dof("lumbar")])
    assert np.abs(thorax_deg).max() == pytest.approx(e.max_thorax_pitch_deg) and e.max_thorax_pitch_deg < 10.0
    assert traj.com_m[-1, 0] - traj.com_m[0, 0] > 2.0  # it went somewhere
    # the arms swing opposite the legs (ARM_SWING_RAD_PER_M): the right arm back as the right leg goes forward
    ch = character()
    legs = traj.qpos[:, ch.dof("hip_r")] - traj.qpos[:, ch.dof("hip_l")]  # < 0: the right thigh ahead
    arms = traj.qpos[:, ch.dof("shoulder_r")] - traj.qpos[:, ch.dof("shoulder_l")]  # > 0: the right arm behind
    walking = (traj.time_s > 0.5) & (traj.time_s < traj.footprints[-2][1])
    assert np.corrcoef(legs[walking], arms[walking])[0, 1] < -0.8
    assert np.degrees(np.abs(traj.qpos[walking, ch.dof("shoulder_r")])).max() > 5.0
    assert np.degrees(np.abs(traj.qpos[-1, [ch.dof("shoulder_r"), ch.dof("shoulder_l")]])).max() < 1.0  # hanging


def test_the_walking_pattern_is_what_makes_the_walk_a_success(monkeypatch):
    """Without ``GaitPattern`` (v0.6's plan) the 0.4 m / 0.5 s walk bounces: its CoP reaches a foot's edge
    (``cop_margin``) and its thorax pitches past 10 deg; with it, a success (docs/stepping.md, *The walking
    pattern*, has each part removed)."""
    import cmrt.control.stepping as stepping

    task = resolve_task("walk")
    full = evaluate(task, simulate_batch(task, [None], record=False)[0])
    plain = stepping.StepConfig.from_task
    monkeypatch.setattr(stepping.StepConfig, "from_task",
                        staticmethod(lambda params: plain(params) and dataclasses.replace(plain(params), gait=None)))
    bare = evaluate(task, simulate(task))
    assert full.success and not bare.success and "cop_margin" in bare.failed_rules and not bare.fell
    assert bare.max_thorax_pitch_deg > 10.0 and bare.max_touchdown_force_bw > full.max_touchdown_force_bw


def test_the_capture_point_over_a_moving_cop_reaches_its_end():
    """``_dcm_start``: from the capture point it returns, xi' = omega (xi - p) over a CoP moving linearly from
    ``anchor_start`` to ``anchor_end`` reaches ``xi_end`` after the segment (scipy's integrator); a still CoP is the
    plain pendulum's xi_start = a + (xi_end - a) exp(-omega L)."""
    from scipy.integrate import solve_ivp

    from cmrt.control.stepping import _dcm_start

    omega, length_s, p0, p1, xi_end = 3.2, 0.6, 0.10, 0.20, 0.45
    xi0 = _dcm_start(xi_end, p0, p1, length_s, omega)
    run = solve_ivp(lambda t, xi: omega * (xi - (p0 + (p1 - p0) * t / length_s)), (0.0, length_s), [xi0],
                    rtol=1e-11, atol=1e-13)
    assert run.y[0, -1] == pytest.approx(xi_end, abs=1e-8)
    assert _dcm_start(xi_end, p0, p0, length_s, omega) == pytest.approx(p0 + (xi_end - p0) * np.exp(-omega * length_s))


@pytest.mark.parametrize("start_s", [1.5, 2.0, 2.5])
@pytest.mark.parametrize("force_n", [150.0, -150.0])
def test_a_push_during_the_walk_is_taken(force_n, start_s):
    """+-150 N x 0.1 s at any phase of the walk (docs/stepping.md has the others): balance kept, every step
    landed, a success."""
    task = resolve_task("walk", params={"push_force_n": force_n, "push_start_s": start_s})
    e = evaluate(task, simulate_batch(task, [None], record=False)[0])
    assert e.success and e.steps == e.footsteps_landed == len(task.steps), e


def test_a_hard_push_during_the_walk_moves_the_plans_steps():
    """+150 N for 0.1 s at 2.0 s (the issue's push): the capture point's error moves the pushed step's landing; the
    plan absorbs it without a step of its own."""
    task = resolve_task("walk", params={"push_force_n": 150.0, "push_start_s": 2.0})
    e = evaluate(task, simulate_batch(task, [None], record=False)[0])
    assert _stepped(e, set(e.failed_rules) & STEPPING_OPEN) and e.steps == len(task.steps), e


@pytest.mark.parametrize("takes_over", [True, False])
def test_a_push_the_plan_cannot_absorb_is_taken_over_by_reactive_steps(takes_over, monkeypatch):
    """+250 N at 1.5 s into the 0.6 m/s walk: the supervisor adds a reactive step, then the plan goes on with the
    trailing foot (no foot steps twice running), every planned step lands where asked and the body comes to rest;
    without the takeover the body falls. (Not every hard push is saved by it - +250 N at 2.5 s is a success without
    the takeover and falls with it: docs/stepping.md.)"""
    import math

    import cmrt.control.stepping as stepping

    if not takes_over:
        monkeypatch.setattr(stepping, "TAKEOVER_ERROR_M", math.inf)
    task = resolve_task("walk", params={"push_force_n": 250.0, "push_start_s": 1.5})
    traj = simulate_batch(task, [None], record=False)[0]
    e = evaluate(task, traj)
    assert (e.performed is not False and not e.fell) is takes_over, e
    if takes_over:
        assert _stepped(e, set(e.failed_rules) & STEPPING_OPEN) and e.steps > len(task.steps), e
        feet = [foot for foot, _, _ in traj.footprints]
        assert all(a != b for a, b in zip(feet, feet[1:], strict=False)), feet
        assert e.peak_normal_force_bw < 3.0


def test_a_plan_is_deterministic_and_independent_of_its_batch():
    task = resolve_task("stand", params={"clip_s": 3.0}, steps=TWO_STEPS)
    one = simulate_batch(task, [None])[0]
    for traj in simulate_batch(task, [None, None]):
        assert np.array_equal(one.qpos, traj.qpos, equal_nan=True)
        assert traj.footprints == one.footprints and traj.footstep_errors_m == one.footstep_errors_m


def test_a_fast_directed_step_plan_is_optimized_stored_and_replayed(tmp_path):
    """Two 0.45 m steps of 0.3 s each and the feet brought together: without a CMRT not a success (the CoP ends on
    a foot's edge); the CMRT displaces the plan's capture point (anticipation for steps) and ``cmrt optimize`` finds a
    better one, stored and replayed exactly (docs/stepping.md, *Anticipation for a fast plan*)."""
    import json

    from tests.service_helpers import cmrt

    args = ["stand", "--set", "clip_s=3.5", "--steps", "R:+0.45:0.3,L:+0.9:0.3,R:+0.9:0.3"]
    store = tmp_path / "s.sqlite"
    out = cmrt("optimize", *args, "--seed", "1", "--max-evals", "20", "--json", store=store)
    assert out.returncode == 0, out.stderr
    run = json.loads(out.stdout)
    # without a CMRT the body keeps its balance but its CoP reaches a foot's edge; the best CMRT found in 20
    # evaluations lowers the objective and lands every step (60 evaluations find a success: docs/stepping.md)
    assert run["baseline_success"] is False and run["fell"] is False
    assert run["best_objective"] < run["baseline_objective"]
    replay = cmrt("simulate", *args, "--curve", str(run["run_id"]), "--json", store=store)
    assert replay.returncode == 0, replay.stderr
    result = json.loads(replay.stdout)
    assert not result["fell"] and result["footsteps_landed"] == 3
    assert set(result["failed_rules"]) <= STEPPING_OPEN
    assert result["objective"] == pytest.approx(run["best_objective"], rel=1e-9)
