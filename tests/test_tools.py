"""The measurement tools in tools/: run as scripts, the way their docstrings say."""

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cmrt.optimize import OptimizeSettings, new_state

ROOT = Path(__file__).resolve().parent.parent
TOOLS = ROOT / "tools"


def run_tool(name: str, *args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, str(TOOLS / name), *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


def load_tool(name: str):
    """A tool script as a module (registered first: its dataclasses look their module up)."""
    module_name = "tools_" + name.removesuffix(".py")
    if module_name not in sys.modules:
        spec = importlib.util.spec_from_file_location(module_name, TOOLS / name)
        module = importlib.util.module_from_spec(spec)
        sys.modules[module_name] = module
        spec.loader.exec_module(module)
    return sys.modules[module_name]


# --- tools/random_success.py ---------------------------------------------------------------------

def test_random_success_draws_from_the_cold_optimizers_start():
    """The same mean, step size and covariance as the first generation of ``cmrt optimize --init none``."""
    tool = load_tool("random_success.py")
    dist = tool.StartDistribution.cold()
    es = new_state(OptimizeSettings()).es
    assert np.array_equal(dist.mean, np.zeros(8)) and dist.sigma == OptimizeSettings().sigma0
    assert np.allclose(dist.cov_chol @ dist.cov_chol.T, es.sm.C, rtol=0, atol=1e-12)
    xs = dist.draw(np.random.default_rng(0), 20_000)
    assert np.allclose(xs.mean(axis=0), 0.0, atol=0.02) and np.allclose(xs.std(axis=0), 0.5, rtol=0.03)
    state = np.random.get_state()[1].copy()
    dist.draw(np.random.default_rng(1), 5)
    assert np.array_equal(np.random.get_state()[1], state)  # numpy's global RNG untouched


def test_wilson_interval():
    tool = load_tool("random_success.py")
    lo, hi = tool.wilson_interval(0, 4)
    assert lo == 0.0 and hi == pytest.approx(0.4899, abs=1e-4)
    lo, hi = tool.wilson_interval(50, 100)
    assert lo == pytest.approx(0.4038, abs=1e-4) and hi == pytest.approx(0.5962, abs=1e-4)
    assert tool.wilson_interval(7, 7)[1] == 1.0


def test_random_success_tool_json_is_reproducible():
    args = ("bend", "--speed", "0.4", "--samples", "4", "--seed", "3", "--json")
    first, again = run_tool("random_success.py", *args), run_tool("random_success.py", *args)
    assert first.returncode == 0, first.stderr
    out = json.loads(first.stdout)
    for key in ("success_fraction", "under_threshold_fraction", "samples", "fell_fraction", "not_performed_fraction",
                "objective_median", "objective_min", "success_fraction_wilson95", "seed", "wall_s", "machine"):
        assert key in out
    assert out["samples"] == 4 and out["seed"] == 3
    assert out["success_fraction"] == out["successes"] / out["samples"]
    assert 0 <= out["under_threshold_fraction"] <= out["success_fraction"]
    assert 0 <= out["fell_fraction"] + out["not_performed_fraction"] + out["success_fraction"] <= 1
    lo, hi = out["success_fraction_wilson95"]
    assert lo <= out["success_fraction"] <= hi
    assert out["objective_min"] <= out["objective_median"]
    redo = json.loads(again.stdout)
    assert {k: v for k, v in redo.items() if k != "wall_s"} == {k: v for k, v in out.items() if k != "wall_s"}


@pytest.mark.parametrize("args, message", [
    (("nosuch",), "unknown task"),
    (("bend", "--samples", "0"), "--samples must be an integer"),
    (("bend", "--samples", "many"), "--samples must be an integer"),
    (("bend", "--seed", "-1"), "--seed must be an integer"),
    (("bend", "--speed", "99"), "--speed"),
    (("bend", "--set", "nope=1"), "--set"),
])
def test_random_success_bad_input_is_one_line_and_exit_2(args, message, capsys):
    tool = load_tool("random_success.py")
    assert tool.main(list(args)) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and err.startswith("error: ")


# --- tools/success_rate.py -----------------------------------------------------------------------

def test_success_rate_summary_of_dict_rows():
    """The summary reads the rows as the dicts measure() builds (it used attribute access and crashed)."""
    from cmrt.task import load_task

    tool = load_tool("success_rate.py")
    task = load_task("bend").with_speed(0.4)  # stop_threshold 0.7
    rows = [{"seed": 1, "success": True, "best_objective": 0.6, "first_success_evals": 30, "wall_s": 1.0},
            {"seed": 2, "success": True, "best_objective": 0.9, "first_success_evals": 50, "wall_s": 2.0},
            {"seed": 3, "success": False, "best_objective": 0.5, "first_success_evals": None, "wall_s": 3.0},
            {"seed": 4, "success": False, "best_objective": 7.0, "first_success_evals": None, "wall_s": 4.0}]
    out = tool.summary(task, [1, 2, 3, 4], "none", 100, rows)
    assert out["success_rate"] == 0.5
    assert out["under_threshold_rate"] == 0.25  # a success below 0.7; seed 3 is below but no success
    assert out["median_evals_to_success"] == 40 and out["worst_evals_to_success"] == 50
    assert out["wall_s"] == 10.0 and out["stop_threshold"] == 0.7


def test_success_rate_tool_runs_to_its_summary():
    """A real run of the script on a tiny budget, through the summary after the last seed."""
    r = run_tool("success_rate.py", "bend", "--speed", "0.4", "--seeds", "1-2", "--max-evals", "10", "--json",
                 "--quiet")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["seeds"] == [1, 2] and len(out["runs"]) == 2
    assert out["success_rate"] == sum(row["success"] for row in out["runs"]) / 2
    under = sum(row["success"] and row["best_objective"] < out["stop_threshold"] for row in out["runs"]) / 2
    assert out["under_threshold_rate"] == under <= out["success_rate"]
    assert all(row["evaluations"] <= 10 for row in out["runs"])
    text = run_tool("success_rate.py", "rise", "--seeds", "1", "--max-evals", "10", "--quiet")
    assert text.returncode == 0, text.stderr
    assert "below the threshold" in text.stdout and "seed 1:" in text.stdout


def test_success_rate_bad_seeds_exit_2():
    r = run_tool("success_rate.py", "bend", "--seeds", "x-y", "--quiet")
    assert r.returncode == 2 and r.stderr.startswith("error: ")


# --- tools/analyze_reference.py ------------------------------------------------------------------

def test_analyze_reference_band_closes_with_the_load():
    tool = load_tool("analyze_reference.py")
    lo, hi = tool.cop_band(np.array([686.7, 160.0, 100.0]), -0.06, 0.18, 40.0)
    assert lo[0] == pytest.approx(-0.06 + 80 * 0.24 / 686.7) and hi[0] == pytest.approx(0.18 - 80 * 0.24 / 686.7)
    assert lo[1] == pytest.approx(hi[1]) == pytest.approx(0.06)  # 4 x 40 N: only the support centre
    assert lo[2] > hi[2]  # below it: closed
    assert tool.excess(np.array([0.0, 0.1]), np.array([-0.05, -0.05]), np.array([0.15, 0.05])) == pytest.approx(0.05)
    assert tool.excess(np.zeros(3), lo, hi) == float("inf")


def test_analyze_reference_a_pre_shift_needs_time():
    """A CoP needed 3 cm beyond the toe side of the band for 0.6 s: a shift built beforehand removes it; one
    that may only start with the need cannot (moving the CoM back means first pushing the CoP forward)."""
    tool = load_tool("analyze_reference.py")
    n, step = 200, 0.01
    band_lo, band_hi = np.full(n, -0.03), np.full(n, 0.15)
    cop = np.full(n, 0.06)
    cop[100:160] = 0.18
    arm = np.full(n, 0.09)  # m c_z / F_z at body weight, s^2
    anyshift, rng = tool.best_shift(cop, band_lo, band_hi, arm, step)
    late, _ = tool.best_shift(cop, band_lo, band_hi, arm, step, free_from=100)
    none = tool.excess(cop, band_lo, band_hi)
    assert none == pytest.approx(0.03)
    assert anyshift < 0 and rng[0] < -0.03  # the CoM moved back beforehand
    assert 0.01 < late < none  # a reaction helps, but not enough
    friction, _ = tool.best_shift(cop, band_lo, band_hi, arm, step, fx_room=(np.zeros(n), np.zeros(n)), mass_kg=70)
    assert friction == pytest.approx(0.03, abs=1e-6)  # no horizontal force to spare: no shift


def test_analyze_reference_tool_json():
    r = run_tool("analyze_reference.py", "bend", "--speeds", "1.2", "--json")
    assert r.returncode == 0, r.stderr
    (row,) = json.loads(r.stdout)
    assert row["speed"] == 1.2 and row["possible"] and row["min_vertical_force_bw"] > 0
    ex = row["cop_excess_m"]
    assert ex["any"] <= ex["from_motion_start"] <= ex["none"]  # more freedom never hurts
    assert row["max_joint_speed_rad_s"] > 0 and len(row["capture_point_range_m"]) == 2


# --- tools/bend_search.py ------------------------------------------------------------------------

def test_bend_search_draws_within_its_ranges():
    tool = load_tool("bend_search.py")
    rng = np.random.default_rng(0)
    for _ in range(50):
        end, timing = tool.draw(rng)
        assert all(lo <= end[k] <= hi for k, (lo, hi) in tool.POSE_DEG.items())
        for joints in tool.GROUPS.values():
            (a, b), *rest = [timing[j] for j in joints]
            assert 0.0 <= a <= 0.3 and 0.7 <= b <= 1.0 and all(w == [a, b] for w in rest)


def test_bend_search_tool_json():
    r = run_tool("bend_search.py", "--samples", "3", "--seed", "1", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["samples"] == 3 and out["possible"] == len(out["rows"]) and out["simulated"] <= out["possible"]
    assert sum(b["n"] for b in out["bins"]) == out["simulated"]
    for row in out["rows"]:
        if "success" in row:
            assert row["ref_max_joint_speed_rad_s"] <= 25 and isinstance(row["success"], bool)
    assert run_tool("bend_search.py", "--samples", "0").returncode == 2
