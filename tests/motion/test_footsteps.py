"""Footstep plans (cmrt.motion.footsteps): the --steps syntax, the task-file form, and the plans refused."""

import pytest

from cmrt.errors import CmrtError
from cmrt.motion.footsteps import PlannedStep, check_plan, parse_steps, plan_text, timeline
from cmrt.motion.taskfile import load_task, resolve_task, task_from_dict


def test_the_cli_syntax_reads_foot_target_duration_and_an_optional_start():
    plan = parse_steps("R:+0.30:0.6, l:0.60:0.5:2.0")
    assert plan == (PlannedStep(0, 0.30, 0.6), PlannedStep(1, 0.60, 0.5, 2.0))
    assert parse_steps(plan_text(plan)) == plan


def test_steps_without_a_start_follow_the_one_before():
    """The first lifts off after FIRST_STEP_S of standing, each next DOUBLE_SUPPORT_S after the last landed."""
    (a0, a1), (b0, b1), (c0, c1) = timeline(parse_steps("R:+0.3:0.6,L:+0.6:0.5,R:+0.6:0.4:3.0"))
    assert (a0, a1) == pytest.approx((0.5, 1.1))
    assert (b0, b1) == pytest.approx((1.25, 1.75))
    assert (c0, c1) == pytest.approx((3.0, 3.4))


@pytest.mark.parametrize("text,match", [
    ("R:+0.30", "must be foot:x_m:duration_s"),
    ("X:+0.3:0.6", "the foot must be R or L"),
    ("R:inf:0.6", "must be finite"),
    ("R:+0.60:0.6", "a leg reaches 0.45 m forward"),
    ("R:-0.40:0.6", "and 0.3 m back"),
    ("R:+0.30:0.6,L:+0.80:0.6", "lands \\+0.50 m from the stance foot"),
    ("R:+0.30:0.1", "a step takes"),
    ("R:+0.3:0.6:1.0,L:+0.6:0.6:1.2", "steps overlap"),
    ("R:+0.3:0.6:2.0,L:+0.6:0.6:0.5", "out of order"),
    ("", "--steps needs"),
])
def test_a_plan_no_leg_can_do_is_refused_in_one_line(text, match):
    with pytest.raises(CmrtError, match=match) as info:
        resolve_task("stand", steps=text)
    assert "\n" not in str(info.value)


def test_the_clip_must_see_the_body_come_to_rest_after_the_last_step():
    with pytest.raises(CmrtError, match="clip_s must be at least 1.6 s"):
        resolve_task("stand", params={"clip_s": 1.0}, steps="R:+0.3:0.6")
    check_plan(parse_steps("R:+0.3:0.6"), clip_s=1.6)


def test_a_plan_is_part_of_the_task_its_definition_and_its_hash():
    """Stored with a run (``to_dict`` round-trips through ``task_from_dict``); a plan changes the content hash,
    no plan leaves every existing hash as it was."""
    plain = load_task("stand")
    stepped = plain.with_steps(parse_steps("R:+0.30:0.6,L:+0.60:0.6"))
    assert "steps" not in plain.to_dict()
    assert stepped.content_hash() != plain.content_hash()
    again = task_from_dict(stepped.to_dict(), source="stored run")
    assert again.steps == stepped.steps and again.content_hash() == stepped.content_hash()


def test_a_task_file_takes_a_list_of_steps(tmp_path):
    path = tmp_path / "two.toml"
    path.write_text('name = "two"\nsteps = [{foot = "R", x_m = 0.3, duration_s = 0.6},\n'
                    '         {foot = "L", x_m = 0.6, duration_s = 0.6, start_s = 1.5}]\n[params]\nclip_s = 4.0\n')
    task = load_task(str(path))
    assert task.steps == (PlannedStep(0, 0.3, 0.6), PlannedStep(1, 0.6, 0.6, 1.5))
    path.write_text('name = "bad"\nsteps = [{foot = "R", x_m = 0.3}]\n')
    with pytest.raises(CmrtError, match="steps\\[1\\] must be a table of foot, x_m, duration_s"):
        load_task(str(path))


def test_the_cli_takes_steps_and_refuses_a_bad_plan_before_the_store(tmp_path):
    import json

    from tests.service_helpers import cmrt

    out = cmrt("simulate", "stand", "--set", "clip_s=3", "--steps", "R:+0.30:0.6,L:+0.60:0.6", "--json")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert result["steps"] == 2 and result["footsteps_landed"] == 2 and not result["fell"]
    assert result["failed_rules"] == [] and result["success"]  # standing in the stance over its feet (v0.5)
    store = tmp_path / "s.sqlite"
    out = cmrt("submit", "stand", "--steps", "R:+0.90:0.6", store=store)
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert "a leg reaches" in out.stderr and not store.exists()


def test_planned_step_s_is_a_plans_speed():
    """``planned_step_s`` > 0 gives every planned step that duration (the stride task's speed), checked as a plan
    is; the steps as written are kept (and compared when CMRTs are matched); at 0 nothing changes, hash included."""
    stride = load_task("stride")
    assert stride.speed_param == "planned_step_s"
    fast, slow = stride.with_speed(0.35), stride.with_speed(0.6)
    assert [s.duration_s for s in fast.plan] == [0.35, 0.35] and [s.duration_s for s in slow.plan] == [0.6, 0.6]
    assert fast.steps == slow.steps and fast.content_hash() != slow.content_hash()
    assert [s.x_m for s in slow.plan] == [s.x_m for s in slow.steps]
    plain = resolve_task("stand", params={"clip_s": 3.0}, steps="R:+0.3:0.6")
    assert plain.plan == plain.steps
    assert plain.with_params(planned_step_s=0.0).content_hash() == plain.content_hash()
    assert [s.duration_s for s in plain.with_params(planned_step_s=0.5).plan] == [0.5]
    with pytest.raises(CmrtError, match="a step takes 0.3-1.5 s, got 0.2"):
        plain.with_params(planned_step_s=0.2)
    with pytest.raises(CmrtError, match="planned_step_s sets the duration of a footstep plan"):
        load_task("stand").with_params(planned_step_s=0.5)


def test_the_cli_refuses_planned_step_s_without_a_plan(tmp_path):
    from tests.service_helpers import cmrt

    store = tmp_path / "s.sqlite"
    out = cmrt("submit", "stand", "--set", "planned_step_s=0.5", store=store)
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert "planned_step_s" in out.stderr and not store.exists()


def test_the_stepping_parameters_are_in_a_plans_hash():
    """A plan is carried out by the stepping supervisor, so its step height changes the physics (and the hash)
    even with ``stepping`` 0; without a plan and with ``stepping`` 0 it changes neither."""
    walk = load_task("walk")
    assert walk.with_params(step_height_m=0.08).content_hash() != walk.content_hash()
    stand = load_task("stand")
    assert stand.with_params(step_height_m=0.08).content_hash() == stand.content_hash()
