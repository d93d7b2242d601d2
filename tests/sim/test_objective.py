"""The objective's diagnostics (docs/controller.md, *Diagnostics*): planned vs executed CoP, timing lag, fall
direction and the topple after a fall - on synthetic trajectories where the answer is known, and on clips."""

import dataclasses

import numpy as np
import pytest

from cmrt import evaluate, load_task, simulate
from cmrt.body.character import character
from cmrt.sim.objective import TRACE_ONLY_FIELDS, timing_lag_s
from cmrt.sim.simulate import Trajectory

DT = 0.002


@pytest.fixture(scope="module")
def bend():
    return load_task("bend").with_speed(0.4)


def played(task, qpos: np.ndarray, fall_time_s: float | None = None) -> Trajectory:
    """A trajectory whose joint angles are ``qpos`` (every step); what timing_lag_s does not read is NaN."""
    n = qpos.shape[0]
    arrays = {f.name: np.full(n, np.nan) for f in dataclasses.fields(Trajectory) if f.type == "np.ndarray"}
    arrays.update(time_s=np.arange(n) * DT, qpos=qpos, protective=np.zeros(n, bool), final_qpos=qpos[-1])
    return Trajectory(**arrays, clip_s=task.clip_s, fell=fall_time_s is not None, fall_time_s=fall_time_s,
                      fall_reason=None, diverged=False, final_com_speed_m_s=0.0)


def reference_at(task, t: np.ndarray) -> np.ndarray:
    return np.array(task.reference(t)[0])


def clip_times(task) -> np.ndarray:
    return np.arange(int(round((task.clip_s + task.tail_s) / DT))) * DT


def test_the_reference_itself_has_no_lag(bend):
    t = clip_times(bend)
    assert timing_lag_s(bend, played(bend, reference_at(bend, t))) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("delay_s", [0.05, 0.12])
def test_a_delayed_reference_lags_by_its_delay(bend, delay_s):
    t = clip_times(bend)
    assert timing_lag_s(bend, played(bend, reference_at(bend, t - delay_s))) == pytest.approx(delay_s, abs=1e-6)


def test_a_motion_done_half_way_or_slowed_down_lags_a_lot(bend):
    """What a delay does not explain counts as lag: going half way, or at half speed, is not 'on time'."""
    t = clip_times(bend)
    start, q = bend.start_qpos(), reference_at(bend, t)
    half = start + 0.5 * (q - start)
    assert timing_lag_s(bend, played(bend, half)) > 0.1  # T = 0.4 s: a quarter of the motion's time and more
    p = bend.preparation_s
    slow = reference_at(bend, np.where(t > p, p + 0.5 * (t - p), t))
    assert timing_lag_s(bend, played(bend, slow)) > 0.1
    small_noise = q + 0.01 * np.sin(40 * t)[:, None]  # tracking noise of 0.01 rad: a few ms, not a lag
    assert timing_lag_s(bend, played(bend, small_noise)) < 0.01


def test_timing_lag_is_none_without_a_pose_change_or_a_window():
    stand = load_task("stand")
    t = clip_times(stand)[:500]
    assert timing_lag_s(stand, played(stand, reference_at(stand, t))) is None
    bend = load_task("bend").with_speed(0.4)
    t = clip_times(bend)
    assert timing_lag_s(bend, played(bend, reference_at(bend, t), fall_time_s=0.5)) is None  # fell before P


def test_stand_plan_cop_is_met_and_scoring_runs_give_the_same_verdict():
    """Quiet standing: the CoP planned at each control step is the one the touch sensors measure in the step
    its torques act in, to < 1 mm, in a recorded run and in a scoring run alike (the plan gap enters the verdict,
    so the optimizer's runs measure it too); only the trace-only figures are left out of a scoring run."""
    task = load_task("stand").with_params(clip_s=3.0)
    traj = simulate(task)
    ev = evaluate(task, traj)
    assert ev.max_plan_cop_error_m is not None and ev.max_plan_cop_error_m < 0.001
    control = np.isfinite(traj.plan_cop_x_m)
    assert control.sum() == pytest.approx(traj.time_s.size / 4, abs=1)  # every control step (125 Hz), no others
    assert ev.timing_lag_s is None and ev.fall_direction is None and ev.after_fall_floor_contact_s is None
    scored = evaluate(task, simulate(task, record=False))
    assert "max_plan_cop_error_m" not in TRACE_ONLY_FIELDS
    assert all(getattr(scored, name) is None for name in TRACE_ONLY_FIELDS)
    assert scored.max_plan_cop_error_m == ev.max_plan_cop_error_m
    assert scored.scored() == ev.scored() and ev.success and ev.failed_rules == ()


@pytest.mark.parametrize("force_n, direction", [(250.0, "forward"), (-250.0, "backward")])
def test_a_push_falls_the_way_it_pushes_and_the_topple_is_measured(force_n, direction):
    task = load_task("stand").with_params(push_force_n=force_n, push_start_s=2.0, push_duration_s=0.1, clip_s=4.0)
    traj = simulate(task)
    ev = evaluate(task, traj)
    assert ev.fell and ev.fall_direction == direction and ev.fall_direction_source == "topple"
    scored = evaluate(task, simulate(task, record=False))
    assert scored.fall_direction == direction and scored.fall_direction_source == "capture_point"
    assert scored.after_fall_max_joint_speed_rad_s is None and scored.max_plan_cop_error_m == ev.max_plan_cop_error_m
    assert scored.scored() == ev.scored()
    # the topple: from the fall to the first non-foot floor contact, which the trace shows
    contact = ev.after_fall_floor_contact_s
    assert contact is not None and ev.fall_time_s < contact <= traj.time_s[-1]
    k, c = (int(np.searchsorted(traj.time_s, x - 1e-9)) for x in (ev.fall_time_s, contact))
    assert traj.lowest_body_z_m[c] < 0.0 and np.all(traj.lowest_body_z_m[k:c] >= 0.0)
    dofs = list(character().actuated_dofs)
    assert ev.after_fall_max_joint_speed_rad_s == np.abs(traj.qvel[k : c + 1][:, dofs]).max() > 1.0
    assert ev.after_fall_peak_foot_force_bw > 0.0 and ev.after_fall_max_foot_lift_m > 0.0
    assert ev.max_plan_cop_error_m < 0.02  # measured 8 mm (+250 N), 1 mm (-250 N): the plan is carried out
    assert np.sign(traj.com_m[c, 0] - traj.support_center_x_m[k]) == np.sign(force_n)


def test_the_on_time_rule(monkeypatch):
    """A pose change done within the RMS bound but late is not performed: ``on_time`` fails and the penalty grows
    with the lag; with ``ENFORCE_TIMING`` off (to show what the rule adds) the lag would only be reported."""
    import cmrt.sim.objective as objective
    from cmrt.sim.objective import evaluate

    slow = load_task("bend").with_speed(1.2)  # RMS bound: the reference 120 ms late; lag bound: 50 ms
    t = clip_times(slow)
    late = played(slow, reference_at(slow, t - 0.08))
    enforced = evaluate(slow, late)
    assert enforced.timing_lag_s == pytest.approx(0.08, abs=1e-6) and enforced.timing_lag_bound_s == 0.05
    assert not enforced.performed and "on_time" in enforced.failed_rules and "performed" not in enforced.failed_rules
    later = evaluate(slow, played(slow, reference_at(slow, t - 0.1)))
    assert later.penalty > enforced.penalty  # graded: later is worse
    assert evaluate(slow, played(slow, reference_at(slow, t - 0.03))).performed  # 30 ms: on time
    monkeypatch.setattr(objective, "ENFORCE_TIMING", False)
    base = evaluate(slow, late)
    assert base.performed and "on_time" not in base.failed_rules and base.penalty < enforced.penalty


def _standing(task, n: int = 3000) -> dict:
    """The arrays of a clip that stood still on the reference with a quiet, well-planned CoP: every rule met."""
    t = np.arange(n) * DT
    q = reference_at(task, t)
    weight = character().mass_kg * 9.81
    cop = np.full(n, 0.06)
    return dict(qpos=q, time_s=t, cop=cop, fz=np.full(n, weight), plan=np.where(np.arange(n) % 4 == 0, cop, np.nan))


def _clip(task, a: dict) -> Trajectory:
    n = a["time_s"].size
    arrays = {f.name: np.full(n, np.nan) for f in dataclasses.fields(Trajectory) if f.type == "np.ndarray"}
    arrays.update(time_s=a["time_s"], qpos=a["qpos"], protective=np.zeros(n, bool), final_qpos=a["qpos"][-1],
                  cop_x_m=a["cop"], normal_force_n=a["fz"], plan_cop_x_m=a["plan"], support_center_x_m=np.full(n, 0.06),
                  support_lo_x_m=np.full(n, -0.06), support_hi_x_m=np.full(n, 0.18), cop_ref_x_m=np.full(n, 0.06),
                  max_joint_speed_rad_s=np.zeros(n))
    return Trajectory(**arrays, clip_s=task.clip_s, fell=False, fall_time_s=None, fall_reason=None, diverged=False,
                      final_com_speed_m_s=0.0, push_n=a.get("push"))


def _break(rule: str, a: dict) -> None:
    """Make the clip ``a`` break one rule at t = 1.5 s (0.6 s into the slow bend's decay)."""
    k = 750
    weight = character().mass_kg * 9.81
    if rule == "plan":
        a["plan"][k] = a["cop"][k] + 0.006
    elif rule == "ground_force":
        a["fz"][k] = 2.6 * weight
    elif rule == "airborne":
        a["fz"][k : k + 10] = 0.0
    elif rule == "cop_margin":
        a["cop"][k - k % 5] = 0.19  # a CoP sample past the toes
    elif rule == "final_pose":
        a["qpos"][-1] = a["qpos"][-1] + 0.2


@pytest.mark.parametrize("rule", ["plan", "ground_force", "airborne", "cop_margin", "final_pose"])
def test_a_success_never_stands_beside_a_figure_that_breaks_its_rule(rule):
    """The one verdict: each plausibility figure over its bound makes the clip fail by that rule (and only that
    one), with a penalty, whatever else went well."""
    slow = load_task("bend").with_speed(1.2)
    good = evaluate(slow, _clip(slow, _standing(slow)))
    assert good.success and good.failed_rules == () and good.penalty == 0.0
    a = _standing(slow)
    _break(rule, a)
    ev = evaluate(slow, _clip(slow, a))
    expected = ("performed",) if rule == "final_pose" else (rule,)  # a pose change's end pose is part of "performed"
    assert not ev.success and ev.failed_rules == expected and ev.penalty >= 5.0


def test_unannounced_pushes_and_touchdowns_are_impacts_for_the_plan_but_not_for_the_ground_force():
    """The controller does not know a push: while it acts the plan cannot be what happens, and the plan gap is not
    judged there; a push's ground force still is."""
    slow = load_task("bend").with_speed(1.2)
    a = _standing(slow)
    a["plan"][752] = a["cop"][752] + 0.02
    a["push"] = np.where((a["time_s"] >= 1.5) & (a["time_s"] < 1.6), 100.0, 0.0)
    assert evaluate(slow, _clip(slow, a)).success
    a["fz"][760] = 2.6 * character().mass_kg * 9.81
    assert evaluate(slow, _clip(slow, a)).failed_rules == ("ground_force",)


def test_a_strike_is_judged_on_time_at_its_contact():
    """A struck prop stops the arm that hits it: a joint not yet at 90 % of its excursion when the hand first touches
    the bag is judged by how far it had got, against when the reference got that far. The same arm frozen at the
    same pose without a contact is late (it never gets there), and one that reaches the bag 60 ms behind its
    reference is late by 60 ms."""
    punch = load_task("punch")
    t = clip_times(punch)
    contact_s = punch.preparation_s + 0.08  # half way out to the via pose (0.16 s)

    def struck(delay_s: float, touch: bool) -> Trajectory:
        q = reference_at(punch, np.minimum(t - delay_s, contact_s - delay_s))  # stopped where it met the bag
        traj = played(punch, q)
        force = np.where(touch & (t >= contact_s) & (t < contact_s + 0.05), 500.0, 0.0)
        return dataclasses.replace(traj, prop_force_n=force)

    assert timing_lag_s(punch, struck(0.0, True)) == pytest.approx(0.0, abs=1e-6)
    assert timing_lag_s(punch, struck(0.06, True)) == pytest.approx(0.06, abs=2e-3)
    assert timing_lag_s(punch, struck(0.0, False)) > 1.0  # no target: an arm that stops half way never arrives


def test_a_stance_foots_cop_roll_is_measured_from_its_heel_and_toe_loads():
    """``stance_cop_roll``: a stance foot whose load moves from its heel to its toe between its touchdown and its
    next lift-off rolled the whole foot (1); the reverse rolled back (-1); the stance the body rests on is not
    counted, nor a plan without footprints."""
    from cmrt.sim.objective import stance_cop_roll

    n = 1000
    t = np.arange(n) * DT
    arrays = {f.name: np.full(n, np.nan) for f in dataclasses.fields(Trajectory) if f.type == "np.ndarray"}
    arrays.update(time_s=t, qpos=np.zeros((n, 15)), protective=np.zeros(n, bool), final_qpos=np.zeros(15))
    force = np.zeros((n, 4))
    ramp = np.clip((t - 0.4) / 0.8, 0.0, 1.0)  # the right foot's stance: 0.4 s to 1.2 s
    force[:, 0], force[:, 1] = 600.0 * (1 - ramp), 600.0 * ramp
    force[:, 2] = force[:, 3] = 50.0
    arrays["point_normal_force_n"] = force

    def clip(footprints, step_times):
        return Trajectory(**arrays, clip_s=2.0, fell=False, fall_time_s=None, fall_reason=None, diverged=False,
                          final_com_speed_m_s=0.0, step_times_s=step_times, footprints=footprints)

    weight = character().mass_kg * 9.81
    rolled = clip(((0, 0.4, 0.0), (1, 1.0, 0.2), (0, 1.6, 0.4)), (0.1, 0.7, 1.2))
    assert stance_cop_roll(rolled, weight) == pytest.approx(1.0, abs=0.03)  # the left foot rests: not counted
    force[:, 0], force[:, 1] = force[:, 1].copy(), force[:, 0].copy()
    assert stance_cop_roll(rolled, weight) == pytest.approx(-1.0, abs=0.03)
    assert stance_cop_roll(clip((), ()), weight) is None


def test_a_foot_slides_only_where_it_is_planted():
    """``foot_slip_m`` counts a heel/toe point while it touches *and* carries ``PLANTED_FORCE_N``: the body slid 2 cm
    along the floor is a 2 cm slip with the feet loaded, none with the feet touching but unloaded (a foot lifting
    off, still within the contact distance)."""
    from cmrt.sim.objective import PLANTED_FORCE_N, foot_slip_m

    task = load_task("stand")
    n = 50
    qpos = np.tile(task.start_qpos(), (n, 1))
    qpos[:, 0] += np.linspace(0.0, 0.02, n)  # the whole body slides 2 cm forward
    traj = played(task, qpos)
    touching = dataclasses.replace(traj, point_contact=np.ones((n, 4)))
    loaded = dataclasses.replace(touching, point_normal_force_n=np.full((n, 4), 10.0 * PLANTED_FORCE_N))
    unloaded = dataclasses.replace(touching, point_normal_force_n=np.zeros((n, 4)))
    assert foot_slip_m(loaded) == pytest.approx(0.02, abs=1e-9)
    assert foot_slip_m(unloaded) == 0.0
