"""The `cmrt` command as a user runs it: real subprocesses, real exit codes."""

import json
import subprocess
import sys

import numpy as np
import pytest


def run(*args):
    return subprocess.run([sys.executable, "-m", "cmrt.cli", *args], capture_output=True, text=True, timeout=300)


@pytest.mark.slow  # cmrt process
def test_simulate_json_fields_and_trace(tmp_path):
    trace = tmp_path / "t.npz"
    r = run("simulate", "bend", "--speed", "1.2", "--json", "--trace", str(trace))
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    for key in ("task", "speed", "objective", "fell", "max_cop_error_m", "final_pose_error_rad", "success",
                "performed", "settled", "min_cop_margin_m", "peak_normal_force_bw", "airborne_s",
                "max_joint_speed_rad_s", "tracking_error_rad", "max_plan_cop_error_m", "timing_lag_s",
                "fall_direction", "fall_direction_source", "after_fall_max_joint_speed_rad_s",
                "after_fall_peak_foot_force_bw", "after_fall_max_foot_lift_m", "after_fall_floor_contact_s"):
        assert key in out
    assert out["task"] == "bend" and out["speed"] == 1.2 and out["fell"] is False and out["success"] is True
    # simulate records: the plan is there (the slow bend meets it to < 1 mm); no fall, no fall figures
    assert 0.0 < out["max_plan_cop_error_m"] < 0.001 and 0.0 <= out["timing_lag_s"] <= 0.04
    assert out["fall_direction"] is None and out["after_fall_floor_contact_s"] is None
    z = np.load(trace)
    for key in (
        "time_s",
        "qpos",
        "qvel",
        "com_m",
        "cop_x_m",
        "support_center_x_m",
        "foot_normal_force_n",
        "cmrt_displacement_m",
        "capture_point_x_m",
        "foot_roll_rad",
        "point_contact",
        "max_joint_speed_rad_s",
        "protective",
        "plan_cop_x_m",
        "lowest_body_z_m",
        "fall_capture_point_x_m",
    ):
        assert key in z.files
    assert z["qpos"].shape == (round((2.6 + 0.5) / 0.002), 15)  # the clip and its standing tail


@pytest.mark.slow  # two cmrt processes
def test_library_curve_and_set_override():
    r = run("simulate", "bend", "--curve", "library", "--json")
    out = json.loads(r.stdout)
    assert r.returncode == 0 and out["success"] is True and out["final_pose_error_rad"] < 0.1
    r = run("simulate", "stand", "--set", "push_force_n=250", "--set", "clip_s=4", "--json")
    out = json.loads(r.stdout)
    assert out["params"]["push_force_n"] == 250 and out["fell"] is True and out["success"] is False


@pytest.mark.slow  # a cmrt process
def test_curve_file(tmp_path):
    f = tmp_path / "c.json"
    f.write_text(json.dumps({"clip_s": 2.6, "knot_times_s": [0.5, 1.0, 1.5, 2.0], "values_m": [0, 0.01, 0, 0]}))
    r = run("simulate", "bend", "--speed", "1.2", "--curve", str(f), "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["curve"] == str(f)


BAD_INPUT = [
    (("simulate", "nosuchtask"), "unknown task"),
    (("simulate", "bend", "--speed", "fast"), "argument --speed: must be a finite number"),
    (("simulate", "bend", "--speed", "9"), "range"),
    (("simulate", "bend", "--set", "duration_s"), "KEY=VALUE"),
    (("simulate", "bend", "--set", "mass=3"), "no parameter"),
    (("simulate", "bend", "--curve", "/nonexistent/c.json"), "cannot read"),
    (("simulate", "stand", "--speed", "0.4"), "no speed"),
    (("simulate", "bend", "--curve", "library", "--speed", "0.9"), "no library CMRT"),
    (("simulate", "bend", "--trace", "/nonexistent/dir/t.npz"), "does not exist"),
    (("frobnicate",), "invalid choice"),
]
#: the fast loop starts one cmrt process (``-m "not slow"``: the entry point works); the other cases are slow
FAST_BAD_INPUT = ("unknown task",)


@pytest.mark.parametrize("args, words", [case if case[1] in FAST_BAD_INPUT
                                         else pytest.param(*case, marks=pytest.mark.slow) for case in BAD_INPUT])
def test_bad_input_is_one_line_and_exit_2(args, words):
    r = run(*args)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("cmrt: error:") and words in lines[0], r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.slow  # cmrt process
def test_bad_curve_file_content(tmp_path):
    f = tmp_path / "c.json"
    f.write_text("[1, 2]")
    r = run("simulate", "bend", "--curve", str(f))
    assert r.returncode == 2 and "must be an object" in r.stderr


_HEAVY = ("mujoco", "numba", "scipy", "cma", "dask", "matplotlib")
_VERBS_WITHOUT_PHYSICS = """
import sys
from cmrt.cli.commands import main
store = sys.argv[1]
codes = [main(["runs", "--store", store, "--json"]), main(["jobs", "--store", store, "--json"]),
         main(["show", "1", "--store", store, "--json"]), main(["export", "1", "--store", store])]
print(codes, sorted(m for m in {HEAVY} if m in sys.modules))
""".replace("{HEAVY}", repr(_HEAVY))


def test_verbs_that_only_read_the_store_load_no_physics(tmp_path):
    """Start-up: listing, showing and exporting runs import neither MuJoCo, numba, scipy, pycma, dask nor
    matplotlib (~4 s together); the parser itself (``--help``) neither. Checked on a store holding a run."""
    from cmrt import load_task
    from cmrt.service import jobs
    from cmrt.service.store import open_store

    path = tmp_path / "s.sqlite"
    with open_store(path) as store:
        jobs.submit(store, load_task("bend").with_speed(0.4), seed=1, init="none")
    r = subprocess.run([sys.executable, "-c", _VERBS_WITHOUT_PHYSICS, str(path)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[-1] == "[0, 0, 0, 0] []"
    r = subprocess.run([sys.executable, "-c", "import sys\nfrom cmrt.cli.commands import build_parser\nbuild_parser()\n"
                        f"print(sorted(m for m in {_HEAVY!r} if m in sys.modules))"],
                       capture_output=True, text=True, timeout=120)
    assert r.stdout.strip() == "[]", r.stderr


def test_optimizer_defaults_come_from_optimize_settings(tmp_path):
    """The optimizer's options default to OptimizeSettings' values, filled in after parsing."""
    from cmrt.optimize.driver import OptimizeSettings
    from cmrt.optimize.settings import FAMILY_SIGMA0

    r = run("submit", "bend", "--speed", "0.4", "--store", str(tmp_path / "s.sqlite"), "--json")
    assert r.returncode == 0, r.stderr
    from cmrt.service.store import open_store

    with open_store(tmp_path / "s.sqlite", readonly=True) as store:
        run_ = store.run(json.loads(r.stdout)["run_id"])
    d = OptimizeSettings()
    assert (run_.seed, run_.max_evals, run_.popsize, run_.min_evals, run_.stall_generations) == (
        d.seed, d.max_evals, d.popsize, d.min_evals, d.stall_generations)
    assert run_.init_source.startswith("library") and run_.sigma0 == FAMILY_SIGMA0  # a warm start's step size


def test_the_package_entry_runs_the_command(capsys):
    """``cmrt.cli.main`` (what ``python -m cmrt.cli`` and the console script run) is the command itself."""
    from cmrt.cli import main

    assert main(["tasks", "--json"]) == 0
    assert "bend" in {row["name"] for row in json.loads(capsys.readouterr().out)}
