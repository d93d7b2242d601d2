import json

import pytest

from cmrt.cli import main

from .service_helpers import cmrt


@pytest.mark.slow  # times every backend, repeated
def test_bench_json_reports_every_figure():
    r = cmrt("bench", "--population", "4", "--repeat", "2", "--backends", "batch,serial", "--json", check=True)
    out = json.loads(r.stdout)
    for key in ("physics_only_s_per_clip", "batched_s_per_clip", "serial_s_per_clip", "ratio_batched_to_physics"):
        assert out[key] > 0
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
