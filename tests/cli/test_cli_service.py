"""The optimization service through the `cmrt` command, as a user drives it."""

import csv
import hashlib
import io
import json

import pytest

from cmrt.cli.commands import main
from tests.service_helpers import FAST_BEND, cmrt


@pytest.fixture(scope="module")
def store_with_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("svc") / "s.sqlite"
    r = cmrt("optimize", *FAST_BEND, "--seed", "2", "--max-evals", "20", "--popsize", "5", "--backend", "serial",
             "--init", "none", "--json", "--no-progress", store=path, check=True)
    return path, json.loads(r.stdout)


@pytest.mark.slow  # shares an optimization run in a cmrt process
def test_optimize_json(store_with_run):
    _, out = store_with_run
    for key in ("run_id", "best_objective", "evaluations", "fell", "wall_s"):
        assert key in out
    assert out["evaluations"] == 20 and out["status"] == "done"
    assert out["init"] == "none" and out["restarts"] == 0 and out["robust"] is False
    rb = out["robustness"]  # every run is replayed on the validation ensemble
    assert rb["validation_total"] == 20 and 0 <= rb["validation_survived"] <= 20


@pytest.mark.slow  # shares an optimization run; five cmrt processes
def test_queries(store_with_run):
    path, out = store_with_run
    rid = out["run_id"]
    runs = json.loads(cmrt("runs", "--task", "bend", "--json", store=path, check=True).stdout)
    assert [r["id"] for r in runs] == [rid]
    show = json.loads(cmrt("show", str(rid), "--json", store=path, check=True).stdout)
    for key in ("status", "best_objective", "best_params", "baseline_objective", "evaluations", "wall_s"):
        assert key in show
    best = json.loads(cmrt("best", *FAST_BEND, "--json", store=path, check=True).stdout)
    assert best["run_id"] == rid and best["best_objective"] == out["best_objective"]
    jobs = json.loads(cmrt("jobs", "--json", store=path, check=True).stdout)
    assert jobs[0]["status"] == "done"
    # the stored best CMRT replays to the stored objective (determinism across processes)
    sim = json.loads(cmrt("simulate", *FAST_BEND, "--curve", str(rid), "--json", store=path, check=True).stdout)
    assert sim["objective"] == out["best_objective"]


@pytest.mark.slow  # shares an optimization run; two cmrt processes
def test_export(store_with_run, tmp_path):
    path, out = store_with_run
    text = cmrt("export", str(out["run_id"]), "--format", "csv", store=path, check=True).stdout
    rows = list(csv.DictReader(io.StringIO(text)))
    assert len(rows) == 20 and min(float(r["objective"]) for r in rows) == out["best_objective"]
    best = min(rows, key=lambda r: float(r["objective"]))  # its knots in s and m are the stored best CMRT's
    assert [float(best[f"knot{i}_time_s"]) for i in range(1, 5)] == out["best_cmrt"]["knot_times_s"]
    assert [float(best[f"knot{i}_displacement_m"]) for i in range(1, 5)] == out["best_cmrt"]["values_m"]
    show = json.loads(cmrt("show", str(out["run_id"]), "--json", store=path, check=True).stdout)
    assert [float(best[f"p{i}"]) for i in range(8)] == show["best_params"]  # the raw CMA-ES vector after them
    dest = tmp_path / "run.json"
    cmrt("export", str(out["run_id"]), "--format", "json", "--out", str(dest), store=path, check=True)
    data = json.loads(dest.read_text())
    assert len(data["evaluations"]) == 20 and len(data["generations"]) == 4


@pytest.mark.slow  # a queued run and a worker process
def test_submit_and_worker(tmp_path):
    path = tmp_path / "q.sqlite"
    sub = json.loads(cmrt("submit", "bend", "--speed", "0.5", "--set", "cop_sample_step_s=0.02", "--seed", "4",
                          "--max-evals", "6", "--popsize", "3", "--init", "none", "--json", store=path,
                          check=True).stdout)
    assert sub["status"] == "queued"
    assert json.loads(cmrt("jobs", "--json", store=path, check=True).stdout)[0]["status"] == "queued"
    w = cmrt("worker", "--until-idle", "--backend", "serial", "--json", store=path, check=True)
    assert json.loads(w.stdout.strip().splitlines()[-1])["finished"] == [sub["run_id"]]
    show = json.loads(cmrt("show", str(sub["run_id"]), "--json", store=path, check=True).stdout)
    assert show["params"]["cop_sample_step_s"] == 0.02 and show["status"] == "done"
    # best filters on the overridden parameters
    assert cmrt("best", "bend", "--speed", "0.5", store=path).returncode == 2
    assert cmrt("best", "bend", "--speed", "0.5", "--set", "cop_sample_step_s=0.02", store=path).returncode == 0


@pytest.mark.slow  # two worker processes
def test_a_worker_says_where_each_search_started_and_why_it_stopped(tmp_path):
    """A warm start that already meets the threshold says so, and names the flags that ask for a search; a cold
    search with no threshold says its budget ran out."""
    path = tmp_path / "q.sqlite"
    cmrt("submit", "punch", store=path, check=True)
    line = cmrt("worker", "--until-idle", "--backend", "serial", store=path, check=True).stdout
    assert ("started from the library CMRT (duration_s 0.4), sigma 0.15; it already met the stop threshold 0.6"
            in line), line
    assert "--init none" in line and "--set stop_threshold=0" in line
    cmrt("submit", "punch", "--init", "none", "--set", "stop_threshold=0", "--max-evals", "20", store=path,
         check=True)
    line = cmrt("worker", "--until-idle", "--backend", "serial", store=path, check=True).stdout
    assert "started cold from the zero CMRT (sigma 0.5); its budget ran out: 20 of 20 evaluations" in line, line
    show = json.loads(cmrt("show", "2", "--json", store=path, check=True).stdout)
    assert show["search"] in line


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("args, words", [
    (("submit", "nosuchtask"), "unknown task"),
    (("submit", "TASKFILE"), "malformed task file"),
    (("submit", "bend", "--speed", "7"), "outside task"),
    (("submit", "bend", "--seed", "1.5"), "--seed: must be an integer"),
    (("optimize", "bend", "--backend", "dask", "--scheduler", "tcp://127.0.0.1:1"), "cannot reach dask scheduler"),
    (("show", "999"), "no run 999"),
    (("best", "bend", "--speed", "1.0"), "no finished run"),
    (("simulate", "bend", "--curve", "999"), "no run 999"),
    (("export", "1", "--format", "xml"), "invalid choice"),
    (("submit", "bend", "--init", "sometimes"), "must be auto, none or a run id"),
    (("submit", "bend", "--init", "999"), "no run 999"),
    (("submit", "bend", "--stall-generations", "0"), "--stall-generations: must be an integer in [1, 100000]"),
    (("submit", "bend", "--max-evals", "20", "--min-evals", "30"), "min-evals 30 is more than the budget"),
    (("submit", "BADROBUST"), "robust: worst_weight"),
])
@pytest.mark.slow  # shares an optimization run; two cmrt processes per case
def test_bad_input_leaves_store_byte_identical(store_with_run, tmp_path, args, words):
    path, _ = store_with_run
    bad_task = tmp_path / "bad.toml"
    bad_task.write_text("name = [unclosed\n")
    bad_robust = tmp_path / "robust.toml"
    bad_robust.write_text('name = "b"\n[params]\nclip_s = 2.6\n[robust]\nworst_weight = 3.0\n')
    args = tuple({"TASKFILE": str(bad_task), "BADROBUST": str(bad_robust)}.get(a, a) for a in args)
    cmrt("runs", store=path, check=True)  # checkpoint the WAL so the main file is complete
    before = digest(path)
    r = cmrt(*args, store=path)
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and words in r.stderr and "Traceback" not in r.stderr
    assert digest(path) == before


@pytest.mark.slow  # three cmrt processes
def test_not_a_store(tmp_path):
    path = tmp_path / "notes.txt"
    path.write_text("my notes\n")
    before = digest(path)
    for args in (("runs",), ("submit", "bend"), ("optimize", "bend", "--backend", "serial")):
        r = cmrt(*args, store=path)
        assert r.returncode == 2 and "not a CMRT store" in r.stderr
    assert digest(path) == before


@pytest.mark.slow  # a 60-evaluation optimization
def test_threshold_stops_only_on_a_success(tmp_path):
    """A user's pose-change task with a generous threshold: candidates that keep balance but do not
    perform the motion score under it, yet only a success may stop the run."""
    task = tmp_path / "lunge.toml"
    task.write_text(
        'name = "lunge"\nspeed_param = "duration_s"\n[params]\nclip_s = 2.6\npreparation_s = 1.0\n'
        "duration_s = 0.4\nstop_threshold = 20.0\n[end_pose_deg]\nlumbar = 30\nhip = -70\nknee = 20\n"
        "shoulder = -60\n"
        "[timing]\nhip = [0.0, 0.6]\nlumbar = [0.0, 0.6]\nknee = [0.4, 1.0]\nankle = [0.4, 1.0]\n"
    )
    path = tmp_path / "t.sqlite"
    out = json.loads(cmrt("optimize", str(task), "--seed", "3", "--max-evals", "60", "--popsize", "6", "--json",
                          "--no-progress", store=path, check=True).stdout)
    data = json.loads(cmrt("export", str(out["run_id"]), "--format", "json", store=path, check=True).stdout)
    evals = data["evaluations"]
    last_gen = max(e["gen"] for e in evals)
    assert any(e["objective"] < 20.0 and not e["success"] for e in evals)  # the loophole was there
    assert not any(e["success"] and e["objective"] < 20.0 for e in evals if e["gen"] < last_gen)
    if out["stop_reason"] == "threshold":
        assert out["success"] is True and out["best_objective"] < 20.0
    else:
        assert out["stop_reason"] == "budget"


def test_not_a_store_in_process(tmp_path, capsys):
    """The same refusal through ``cmrt.cli.main`` in this process: the fast loop's check (no process start)."""
    path = tmp_path / "notes.txt"
    path.write_text("my notes\n")
    before = digest(path)
    for args in (("runs",), ("submit", "bend")):
        assert main([*args, "--store", str(path)]) == 2
        assert "not a CMRT store" in capsys.readouterr().err
    assert digest(path) == before


@pytest.mark.slow  # two short 3D searches and a replay in cmrt processes
def test_a_cmrt_in_x_and_y_through_the_service(tmp_path):
    """punch3d's CMRT acts forward and sideways (12 parameters): optimized into the store, shown and exported with
    its values across, replayed from the store to its objective, and the start of a warm-started search."""
    path = tmp_path / "s.sqlite"
    common = ("--popsize", "6", "--backend", "serial", "--json", "--no-progress")
    out = json.loads(cmrt("optimize", "punch3d", "--seed", "1", "--max-evals", "12", "--init", "none", *common,
                          store=path, check=True).stdout)
    best = out["best_cmrt"]
    assert len(best["cross_values_m"]) == 4 and any(best["cross_values_m"])
    show = json.loads(cmrt("show", str(out["run_id"]), "--json", store=path, check=True).stdout)
    assert len(show["best_params"]) == 12
    rows = list(csv.DictReader(io.StringIO(cmrt("export", str(out["run_id"]), "--format", "csv", store=path,
                                                check=True).stdout)))
    top = min(rows, key=lambda r: float(r["objective"]))
    assert [float(top[f"knot{i}_cross_displacement_m"]) for i in range(1, 5)] == best["cross_values_m"]
    assert "p11" in top and "p12" not in top
    sim = json.loads(cmrt("simulate", "punch3d", "--curve", str(out["run_id"]), "--json", store=path,
                          check=True).stdout)
    assert sim["objective"] == out["best_objective"] and sim["cmrt"] == best
    warm = json.loads(cmrt("optimize", "punch3d", "--seed", "2", "--max-evals", "6", "--init", str(out["run_id"]),
                           *common, store=path, check=True).stdout)
    assert warm["init"] == f"run {out['run_id']}" and warm["best_objective"] <= out["best_objective"]
