"""``cmrt check``: the verdict, its JSON and exit status (0 feasible, 1 not, 2 bad input), and the warning a user's
task file that is not feasible gets when it is simulated or optimized."""

import json
import shutil
from pathlib import Path

import pytest

from cmrt import CmrtError
from cmrt.cli.commands import main

V03_BEND = Path(__file__).parent.parent / "data" / "v03_bend.toml"

KEYS = {"task", "speed", "feasible", "needs_anticipation", "from_onset_suffices", "first_violation",
        "min_vertical_force_bw", "friction_needed", "min_cop_margin_m", "peak_torque_nm", "torque_limit_nm",
        "floor_friction", "min_vertical_force_needed_bw", "keyed", "best", "searches", "ignored", "wall_s"}


def test_a_feasible_task_exits_0_with_its_figures(capsys):
    assert main(["check", "push", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == KEYS
    assert out["feasible"] is True and out["first_violation"] is None and out["task"] == "push"
    assert set(out["searches"]) == {"any", "from_onset", "from_reaction"}
    for s in out["searches"].values():
        assert {"worst_violation", "worst", "com_shift_range_m", "ankle_shift_range_deg", "free_from_s",
                "feasible", "iterations"} <= set(s)
    assert set(out["keyed"]) == set(out["best"]) == {"min_vertical_force_bw", "min_vertical_force_t_s",
                                                     "friction_needed", "min_cop_margin_m", "peak_torque_nm"}
    assert out["peak_torque_nm"].keys() == out["torque_limit_nm"].keys() and out["torque_limit_nm"]["lumbar"] == 300
    assert out["ignored"] == ["the slab's forces on the body (the motion is checked alone)"]


def test_the_v03_fast_bend_exits_1_and_says_why(capsys):
    """The bend shipped until v0.3 (its reference asks the ground to pull): not feasible."""
    assert main(["check", str(V03_BEND), "--speed", "0.4"]) == 1
    text = capsys.readouterr().out
    assert text.startswith("v03-bend --speed 0.4: NOT FEASIBLE: ")
    for row in ("min vertical force (BW)", "lumbar torque (N m)", "from_reaction (t >= 1.10 s)"):
        assert row in text


def test_the_shipped_fast_bend_is_feasible_and_needs_anticipation(capsys):
    assert main(["check", "bend", "--speed", "0.4", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["feasible"] and out["needs_anticipation"] and out["from_onset_suffices"]
    assert out["min_vertical_force_bw"] >= 0.25 and out["searches"]["from_reaction"]["worst_violation"] > 0


@pytest.mark.parametrize("argv, words", [
    (["check", "walk"], "cannot check task 'walk': a footstep plan"),
    (["check", "stand"], "not a pose change"),
    (["check", "bend", "--set", "slope_deg=5"], "not on a still level floor"),
    (["check", "nosuchtask"], "unknown task"),
    (["check", "bend", "--speed", "9"], "--speed"),
])
def test_what_it_cannot_check_is_bad_input(capsys, argv, words):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("cmrt: error: ") and words in err and err.count("\n") == 1


@pytest.fixture
def fast_bend_file(tmp_path):
    """A user's task file: the v0.3 fast bend (its reference asks the ground to pull), copied."""
    path = tmp_path / "my_bend.toml"
    shutil.copyfile(str(V03_BEND), path)
    return path


def test_simulating_a_users_infeasible_task_file_warns_and_runs(fast_bend_file, capsys):
    assert main(["simulate", str(fast_bend_file), "--json"]) == 0
    captured = capsys.readouterr()
    (line,) = captured.err.splitlines()
    assert line.startswith(f"cmrt: warning: {fast_bend_file}: its reference motion cannot be done on time")
    assert "behind the heels at t = " in line and line.endswith(f"(cmrt check {fast_bend_file})")
    assert json.loads(captured.out)["task"] == "v03-bend"  # the run went on
    assert main(["simulate", str(fast_bend_file), "--speed", "1.2", "--json"]) == 0  # feasible: no warning
    assert capsys.readouterr().err == ""


def test_optimizing_a_users_infeasible_task_file_warns_first(fast_bend_file, tmp_path, capsys, monkeypatch):
    def stop(*args, **kwargs):
        raise CmrtError("stopped before optimizing")

    monkeypatch.setattr("cmrt.service.jobs.optimize_now", stop)
    assert main(["optimize", str(fast_bend_file), "--no-progress", "--store", str(tmp_path / "s.sqlite")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("cmrt: warning: ") and err[-1] == "cmrt: error: stopped before optimizing"


def test_shipped_tasks_are_not_checked_at_run_time(capsys, monkeypatch):
    def fail(task):
        raise AssertionError("checked")

    monkeypatch.setattr("cmrt.motion.feasibility.check_reference", fail)
    assert main(["simulate", "bend", "--speed", "0.4", "--json"]) == 0
    assert capsys.readouterr().err == ""
