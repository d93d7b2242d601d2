"""`cmrt simulate` on a 3D task file (docs/examples/stand3d.toml): the 3D body's standing clip and its verdict;
the rest of the CLI refuses a 3D task in one line (exit 2) before it touches a store."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
TASK = str(ROOT / "docs" / "examples" / "stand3d.toml")


def run(*args):
    return subprocess.run([sys.executable, "-m", "cmrt.cli", *args], capture_output=True, text=True, timeout=300)


@pytest.mark.slow  # cmrt processes
def test_a_sideways_push_taken_and_one_that_topples_toward_it(tmp_path):
    taken = run("simulate", TASK, "--set", "push_force_y_n=100", "--json", "--trace", str(tmp_path / "t.npz"))
    assert taken.returncode == 0, taken.stderr
    r = json.loads(taken.stdout)
    assert r["body"] == "humanoid3d" and r["success"] and r["failed_rules"] == [] and not r["fell"]
    assert r["max_plan_cop_error_m"] <= r["verdict_bounds"]["max_plan_cop_error_m"]
    trace = np.load(tmp_path / "t.npz")
    assert trace["qpos"].shape[1] == 32 and len(trace["time_s"]) == len(trace["com_m"])
    fell = json.loads(run("simulate", TASK, "--set", "push_force_y_n=-300", "--json").stdout)
    assert fell["fell"] and fell["failed_rules"][0] == "balance" and fell["fall_direction_xy"][1] < -0.9
    text = run("simulate", TASK, "--set", "push_force_y_n=-300").stdout
    assert "not a success: balance" in text and "judged as: standing (the 3D body)" in text


@pytest.mark.slow  # cmrt processes
def test_what_the_3d_body_cannot_do_yet_is_one_line_and_exit_2(tmp_path):
    store = tmp_path / "s.sqlite"
    for args, says in ((("optimize", TASK, "--store", str(store)), "only `cmrt simulate` runs"),
                       (("simulate", TASK, "--curve", "library"), "no CMRTs yet"),
                       (("simulate", TASK, "--set", "stepping=1"), "--set stepping: not for the humanoid3d body"),
                       (("check", TASK), "only `cmrt simulate` runs")):
        out = run(*args)
        assert out.returncode == 2 and says in out.stderr and len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert not store.exists()
