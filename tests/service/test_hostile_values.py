"""Values a store's schema allows but cmrt never writes (issue 46, items 2 and 5): every one is refused where it is
read - one line and exit 2 from a verb, a run failed with the reason by a worker - and values copied from a store
into a new run are checked like user input. Real SQLite files; the verbs through ``cmrt.cli.main`` in process."""

import json
import sqlite3
import time

import pytest

from cmrt.service.store import open_store
from tests.input_helpers import assert_refused, call, make_store, snapshot


@pytest.fixture
def store(tmp_path):
    """Run 1: a finished bend run (generations, evaluations, its best CMRT); run 2: queued."""
    return make_store(tmp_path / "s.sqlite")


def plant(path, sql, *args):
    con = sqlite3.connect(path)
    con.execute(sql, args)
    con.commit()
    con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    con.close()


def row(path, run_id):
    con = sqlite3.connect(path)
    con.row_factory = sqlite3.Row
    try:
        return dict(con.execute("SELECT * FROM runs WHERE id = ?", (run_id,)).fetchone())
    finally:
        con.close()


INT64_MAX = 2**63 - 1
READS = {  # the red team's cases: each made a verb end in a traceback on 1d2cd70
    "heartbeat at 2**63-1, jobs": (f"UPDATE runs SET heartbeat_at = {INT64_MAX} WHERE id = 1", ["jobs"],
                                   "heartbeat_at"),
    "created at 2**63-1, show": (f"UPDATE runs SET created_at = {INT64_MAX} WHERE id = 1", ["show", "1"], "created_at"),
    "NULL evaluations, show": ("UPDATE runs SET evaluations = NULL WHERE id = 1", ["show", "1"], "evaluations"),
    "NULL evaluations, export": ("UPDATE runs SET evaluations = NULL WHERE id = 1", ["export", "1"], "evaluations"),
    "robustness a list, best": ("UPDATE runs SET robustness = '[1,2]' WHERE id = 1", ["best", "bend"], "robustness"),
    "params a list, best": ("UPDATE runs SET params = '[1, 2]' WHERE id = 1", ["best", "bend"], "params"),
    "text objective, export csv": ("UPDATE evaluations SET objective = 'low' WHERE run_id = 1 AND idx = 3",
                                   ["export", "1", "--format", "csv"], "objective"),
    "blob seconds, export": ("UPDATE evaluations SET seconds = x'00ff' WHERE run_id = 1", ["export", "1"], "seconds"),
    "mean a dict, export": ("UPDATE generations SET mean = '{}' WHERE run_id = 1", ["export", "1"], "mean"),
    "attempt past 2**31, jobs": (f"UPDATE runs SET attempt = {INT64_MAX} WHERE id = 2", ["jobs"], "attempt"),
}


@pytest.mark.parametrize("case", sorted(READS))
def test_a_hostile_value_is_one_line_from_the_verb_that_reads_it(store, capsys, case):
    sql, verb, column = READS[case]
    plant(store, sql)
    before = snapshot(store)
    r = call(capsys, [*verb, "--store", store])
    assert_refused(r, before, snapshot(store), column)


def test_a_done_run_without_its_wall_time_or_baseline_is_shown_with_dashes(store, capsys):
    plant(store, "UPDATE runs SET wall_s = NULL, baseline_objective = NULL WHERE id = 1")
    r = call(capsys, ["best", "bend", "--store", store])
    assert r.rc == 0 and "Traceback" not in r.err, r.err
    assert "done in - s, 0 restarts; started cold" in r.out and "zero CMRT:      objective -" in r.out, r.out


def test_a_stored_curve_is_held_to_what_a_curve_file_may_hold(store, capsys, tmp_path):
    """Knot values of 1e308 m: refused from a file, and now from a stored run too (a traceback before)."""
    best = json.loads(row(store, 1)["best_cmrt"])
    best["values_m"] = [1e308, -1e308, 1e308, 0.0]
    plant(store, "UPDATE runs SET best_cmrt = ? WHERE id = 1", json.dumps(best))
    (tmp_path / "c.json").write_text(json.dumps(best))
    before = snapshot(store)
    for curve in ("1", str(tmp_path / "c.json")):
        r = call(capsys, ["simulate", "bend", "--curve", curve, "--store", store])
        assert_refused(r, before, snapshot(store), "values_m must be a finite number in [-1, 1] m")


@pytest.mark.parametrize("best_params", ["[NaN, 0, 0, 0, 0, 0, 0, 0]", "[1e308, 0, 0, 0, 0, 0, 0, 0]",
                                         "[0, 0, 0, 0, 0, 0, 0, -1e308]", "[0, 0, 0]"])
def test_a_start_copied_from_a_stored_run_is_checked_like_user_input(store, capsys, best_params):
    plant(store, "UPDATE runs SET best_params = ? WHERE id = 1", best_params)
    before = snapshot(store)
    r = call(capsys, ["submit", "bend", "--init", "1", "--store", store])
    assert_refused(r, before, snapshot(store), "best")


def test_a_queued_run_whose_start_point_is_hostile_is_failed_by_the_worker(store, capsys):
    plant(store, "UPDATE runs SET init_params = '[0, 0, 0, 0, 0, 0, 0, 1e308]' WHERE id = 2")
    r = call(capsys, ["worker", "--until-idle", "--store", store])
    assert r.rc == 0, r.err
    failed = row(store, 2)
    assert failed["status"] == "failed" and "start point" in failed["error"], failed["error"]


def test_a_heartbeat_from_the_future_counts_as_stale(store):
    plant(store, "UPDATE runs SET status = 'running', worker = 'ghost:1', attempt = 1, heartbeat_at = ? WHERE id = 2",
          time.time() + 10 * 365 * 86400)
    with open_store(store) as s:
        taken = s.claim("me:1", 60.0)
        assert taken is not None and taken.run_id == 2 and taken.attempt == 2
        run = s.run(2)
    assert run.status == "running" and run.worker == "me:1" and run.retries == 1


def test_a_queued_run_with_an_empty_task_definition_is_failed_not_run(store, capsys):
    """``task_source = '{}'`` ran to done as an empty task on 1d2cd70: the definition must be the run's task."""
    plant(store, "UPDATE runs SET task_source = '{}' WHERE id = 2")
    t0 = time.perf_counter()
    r = call(capsys, ["worker", "--until-idle", "--store", store])
    assert r.rc == 0 and time.perf_counter() - t0 < 20, r.err
    failed = row(store, 2)
    assert failed["status"] == "failed" and "task definition" in failed["error"] and failed["evaluations"] == 0


def test_a_queued_run_at_attempt_2_63_is_failed_with_the_reason_and_jobs_still_lists(store, capsys):
    """The worker exited 1 with OverflowError on 1d2cd70, the run left ``running`` with a REAL attempt."""
    plant(store, f"UPDATE runs SET attempt = {INT64_MAX} WHERE id = 2")
    r = call(capsys, ["worker", "--until-idle", "--store", store])
    assert r.rc == 0 and "attempt" in r.err and r.err.count("\n") == 1, r.err
    failed = row(store, 2)
    assert failed["status"] == "failed" and "attempt is not an integer" in failed["error"]
    plant(store, "UPDATE runs SET attempt = 1 WHERE id = 2")  # whoever repairs it sees the queue again
    assert call(capsys, ["jobs", "--store", store]).rc == 0


def test_every_column_of_every_table_has_its_check():
    """The column tables of ``service.records`` are the schema cmrt's migrations build, column for column."""
    from cmrt.motion.curve import N_PARAMS, N_PARAMS_TWO_AXES
    from cmrt.service import records
    from cmrt.service.store import SCHEMA_VERSION, _expected_schema

    schema = _expected_schema(SCHEMA_VERSION)
    for table, columns in (("runs", records.RUNS), ("generations", records.GENERATIONS),
                           ("evaluations", records.EVALUATIONS), ("meta", records.META)):
        assert sorted(c[1] for c in schema[("table", table)][1]) == sorted(columns), table
    assert records.CMRT_PARAMS == (N_PARAMS, N_PARAMS_TWO_AXES)


def test_a_run_of_an_older_schema_reads_without_its_later_columns(tmp_path, capsys):
    """A read verb does not migrate: columns added after schema 1 read as NULL (their default)."""
    import sqlite_utils

    from cmrt.motion.taskfile import load_task
    from cmrt.service.store import MIGRATIONS

    path, task = tmp_path / "old.sqlite", load_task("bend")
    con = sqlite3.connect(path)
    MIGRATIONS[0](sqlite_utils.Database(con))
    con.execute("INSERT INTO meta VALUES ('app', 'cmrt')")
    con.execute("INSERT INTO runs (task, params, task_hash, task_source, seed, max_evals, popsize, sigma0, min_evals, "
                "created_at) VALUES (?, ?, ?, ?, 1, 10, 10, 0.5, 0, 1.0)",
                (task.name, json.dumps(task.params), task.content_hash(), json.dumps(task.to_dict())))
    con.execute("PRAGMA user_version = 1")
    con.commit()
    con.close()
    before = snapshot(path)
    r = call(capsys, ["show", "1", "--json", "--store", path])
    assert r.rc == 0 and json.loads(r.out)["reference"] == "center" and snapshot(path) == before, r.err
