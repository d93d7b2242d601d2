"""What used to pass in silence (exit 0) and surprise a user later: a mistyped store, a quiet worker,
options that override each other, outputs named like something else, a CMRT made for another task, a
budget smaller than a generation, times and figures a person cannot read."""

import csv
import io
import json
import re
import subprocess
import sys
import time

import pytest

from cmrt.cli.commands import main
from cmrt.errors import CmrtError
from cmrt.motion.taskfile import load_task
from cmrt.service.jobs import submit
from cmrt.service.store import open_store
from tests.service_helpers import as_in_a_terminal

TASK = load_task("bend").with_speed(1.2)


def one_line(err: str) -> bool:
    return err.startswith("cmrt: error: ") and err.count("\n") == 1


@pytest.mark.parametrize("verb", [["worker", "--until-idle"], ["worker"], ["requeue", "1"]])
def test_worker_and_requeue_refuse_a_missing_store(tmp_path, capsys, verb):
    path = tmp_path / "typo.sqlite"
    assert main([*verb, "--store", str(path)]) == 2
    err = capsys.readouterr().err
    assert one_line(err) and "no CMRT store" in err and "cmrt submit" in err, err
    assert not path.exists() and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("verb", [["runs"], ["submit", "bend"], ["worker", "--until-idle"], ["show", "1"],
                                  ["dashboard", "--port", "0"]])
def test_an_empty_store_path_is_bad_input_not_the_default_store(tmp_path, capsys, monkeypatch, verb):
    """``--store ''`` used store/cmrt.sqlite in silence on 1d2cd70 (a submit created it)."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("CMRT_STORE", "")
    assert main([*verb, "--store", ""]) == 2
    err = capsys.readouterr().err
    assert one_line(err) and "an empty store path names no store" in err, err
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(CmrtError, match="empty store path"):
        open_store("")


def test_a_write_verb_says_when_it_creates_a_store(tmp_path, capsys):
    path = tmp_path / "new.sqlite"
    assert main(["submit", "bend", "--speed", "1.2", "--init", "none", "--store", str(path)]) == 0
    assert capsys.readouterr().err == f"cmrt: created a new store at {path}\n"  # the whole path, to copy
    assert main(["submit", "bend", "--speed", "1.2", "--init", "none", "--store", str(path)]) == 0
    assert capsys.readouterr().err == ""  # the second time it is there


def test_speed_and_set_of_the_same_parameter_are_refused(tmp_path, capsys):
    path = tmp_path / "s.sqlite"
    for verb in (["simulate"], ["submit"]):
        assert main([*verb, "bend", "--speed", "0.4", "--set", "duration_s=0.6", "--store", str(path)]) == 2
        err = capsys.readouterr().err
        assert one_line(err) and "--speed sets duration_s" in err, err
    assert not path.exists()


def test_plot_out_is_a_directory_not_a_file_name(tmp_path, capsys):
    (tmp_path / "x.png").mkdir()
    for out in ("x.png", "y.pdf"):  # an existing directory named like a file, and a new name
        assert main(["plot", "--family", "bend", "--out-dir", str(tmp_path / out)]) == 2
        err = capsys.readouterr().err
        assert one_line(err) and "directory the figures go into" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.png"]


@pytest.mark.parametrize("argv", [
    ["simulate", "bend", "--trace", "{tmp}/trace"],  # np.savez would have written trace.npz
    ["sequence", "four-poses", "--trace", "{tmp}/trace.json"],
    ["interpolate", "bend", "--speed", "0.5", "--out", "{tmp}/c.csv"],
    ["export", "1", "--format", "csv", "--out", "{tmp}/run.json"],
])
def test_an_output_without_its_suffix_is_refused(tmp_path, capsys, argv):
    assert main([a.format(tmp=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err
    assert one_line(err) and "must end in" in err, err
    assert list(tmp_path.iterdir()) == []


def test_a_cmrt_file_made_for_another_task_is_refused_unless_forced(tmp_path, capsys):
    curve = tmp_path / "bend05.json"
    assert main(["interpolate", "bend", "--speed", "0.5", "--out", str(curve)]) == 0
    capsys.readouterr()
    assert json.loads(curve.read_text())["task"] == "bend"
    assert main(["simulate", "punch", "--curve", str(curve)]) == 2  # the same 2.6 s clip: it used to run
    err = capsys.readouterr().err
    assert one_line(err) and "made for task 'bend', not 'punch'" in err and "--force" in err, err
    assert main(["simulate", "punch", "--curve", str(curve), "--force", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["task"] == "punch"


def test_a_budget_smaller_than_one_generation_is_refused(tmp_path, capsys):
    path = tmp_path / "s.sqlite"
    assert main(["submit", "bend", "--max-evals", "5", "--store", str(path)]) == 2  # popsize 10
    err = capsys.readouterr().err
    assert one_line(err) and "less than one generation of 10" in err, err
    assert not path.exists()
    assert main(["submit", "bend", "--max-evals", "5", "--popsize", "5", "--store", str(path)]) == 0


def test_show_and_jobs_print_local_iso_times_and_rounded_figures(tmp_path, capsys):
    path = tmp_path / "s.sqlite"
    with open_store(path) as store:
        rid = submit(store, TASK, init="none", sigma0=0.123456789)
    assert main(["show", str(rid), "--store", str(path)]) == 0
    text = capsys.readouterr().out
    created = re.search(r"^created_at\s+(\S+)$", text, re.M).group(1)
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d[+-]\d\d:\d\d", created), created
    assert re.search(r"^sigma0\s+0\.123457$", text, re.M), text
    assert main(["show", str(rid), "--json", "--store", str(path)]) == 0
    data = json.loads(capsys.readouterr().out)  # JSON keeps full precision and unix times
    assert data["sigma0"] == 0.123456789 and abs(data["created_at"] - time.time()) < 600


@pytest.mark.slow  # a worker process and a short optimization
def test_the_worker_says_what_it_waits_for_and_each_run_it_finishes(tmp_path):
    path = tmp_path / "s.sqlite"
    with open_store(path) as store:
        rid = submit(store, TASK, seed=3, max_evals=6, popsize=3, init="none")
    proc = subprocess.Popen([sys.executable, "-m", "cmrt.cli", "worker", "--store", str(path), "--backend", "serial"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=as_in_a_terminal)
    lines = []
    try:
        deadline = time.time() + 300
        while time.time() < deadline:
            line = proc.stdout.readline()
            lines.append(line)
            if "waiting" in line:
                break
    finally:
        proc.terminate()
        proc.communicate(timeout=60)
    assert any(re.search(rf"run {rid} bend --speed 1.2: done, best objective [\d.]+ .*; started cold from the zero "
                         rf"CMRT \(sigma 0.5\); .*6 evaluations", x) for x in lines), lines
    assert "no queued job" in lines[-1] and "Ctrl-C stops" in lines[-1], lines


@pytest.mark.slow  # a short optimization
def test_export_csv_gives_knots_in_seconds_and_metres(tmp_path):
    from cmrt.motion.curve import Cmrt
    from cmrt.service.jobs import optimize_now
    from cmrt.service.query import export_run

    with open_store(tmp_path / "s.sqlite") as store:
        run = optimize_now(store, TASK, seed=2, max_evals=6, popsize=3, init="none")
        rows = list(csv.DictReader(io.StringIO(export_run(store, run.id, "csv"))))
    assert len(rows) == 6
    for r in rows:
        curve = Cmrt.from_params([float(r[f"p{i}"]) for i in range(8)], TASK.clip_s)
        assert [float(r[f"knot{i}_time_s"]) for i in range(1, 5)] == list(curve.knot_times_s)
        assert [float(r[f"knot{i}_displacement_m"]) for i in range(1, 5)] == list(curve.values_m)
        assert 0 < float(r["knot1_time_s"]) < float(r["knot4_time_s"]) < TASK.clip_s
