"""A full disk is "disk full", exit 75, everywhere (issue 46, item 3): a write into a store, a read that must build
the store's WAL index beside it, an output file, a worker's commit (its run given back to the queue first). A hot
rollback journal is named as what it is.

The full disk is real: a tmpfs of 2 MB filled to its last byte (``tests.service_helpers.tiny_disk``; skipped where
the machine does not let us mount one), so SQLite meets ENOSPC exactly where it would on a full disk - and, as there,
says "database or disk is full" or "disk I/O error" depending on which file could not grow. One worker test uses
SQLite's own limit instead (``PRAGMA max_page_count``: SQLite returns SQLITE_FULL, the result code a full disk
gives), so that the path is also covered where nothing can be mounted."""

import hashlib
import os
import sqlite3
import sys
import time

import numpy as np
import pytest

from cmrt.cli.commands import main
from cmrt.errors import DiskFull
from cmrt.motion.taskfile import load_task
from cmrt.optimize import parallel
from cmrt.service.jobs import submit, work
from cmrt.service.store import open_store
from cmrt.sim.objective import EvalRecord
from tests.service_helpers import cmrt, fill, tiny_disk

TASK = load_task("bend").with_speed(0.4)


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def listing(directory):
    return sorted(p.name for p in directory.iterdir())


def queued_store(path, **settings):
    """A store with one queued run (1) whose baseline is already scored: a worker only calls its evaluator."""
    with open_store(path) as s:
        submit(s, TASK, init="none", **settings)
    con = sqlite3.connect(path)
    con.execute("UPDATE runs SET baseline_objective = 7.7, baseline_fell = 0, baseline_success = 0")
    con.commit()
    con.close()
    return path


class Stub(parallel.Evaluator):
    """CMA-ES candidates scored by their squared norm (no physics); ``on_call(n)`` runs before call n returns."""

    on_call = staticmethod(lambda n: None)

    def __call__(self, task, xs):
        self.calls = getattr(self, "calls", 0) + 1
        type(self).on_call(self.calls)
        return [EvalRecord(float(np.sum(np.square(x))), False, 0.0, False) for x in xs]


def test_a_submit_into_a_store_on_a_full_disk_is_disk_full_and_leaves_nothing(tmp_path):
    """1d2cd70: "is a corrupted SQLite file (disk I/O error)", exit 2."""
    with tiny_disk(tmp_path, "2m") as disk:
        path = queued_store(disk / "s.sqlite")
        fill(disk, 0)
        before = digest(path)
        r = cmrt("submit", "bend", "--init", "none", store=path)
        assert r.returncode == 75, r.stderr
        assert r.stderr == f"cmrt: error: store {path}: disk full (free some space and run it again)\n"
        assert listing(disk) == ["filler", "s.sqlite"] and digest(path) == before


def test_reads_that_must_build_the_wal_index_on_a_full_disk_say_disk_full(tmp_path, capsys):
    """A WAL left by a killed writer and no -shm: a reader must create and fill the index beside the store."""
    with tiny_disk(tmp_path, "2m") as disk:
        path = queued_store(disk / "s.sqlite")
        con = sqlite3.connect(path)  # a writer that commits and dies: its -wal stays, we drop the -shm
        con.execute("UPDATE runs SET error = 'x'")
        con.commit()
        wal = (disk / "s.sqlite-wal").read_bytes()
        con.close()
        (disk / "s.sqlite-wal").write_bytes(wal)
        assert listing(disk) == ["s.sqlite", "s.sqlite-wal"]
        fill(disk, 0)
        before = (digest(path), digest(disk / "s.sqlite-wal"))
        for verb in (["runs"], ["jobs"], ["show", "1"], ["export", "1"]):
            assert main([*verb, "--store", str(path)]) == 75, verb
            err = capsys.readouterr().err
            assert err == f"cmrt: error: store {path}: disk full (free some space and run it again)\n", (verb, err)
        assert listing(disk) == ["filler", "s.sqlite", "s.sqlite-wal"]
        assert (digest(path), digest(disk / "s.sqlite-wal")) == before


def test_an_output_file_on_a_full_disk_is_disk_full(tmp_path, capsys):
    path = queued_store(tmp_path / "s.sqlite")
    with tiny_disk(tmp_path, "160k") as disk:
        fill(disk, 0)
        assert main(["export", "1", "--out", str(disk / "e.json"), "--store", str(path)]) == 75
        err = capsys.readouterr().err
        assert "disk full" in err and err.count("\n") == 1, err
        assert listing(disk) == ["filler"]


def test_a_worker_whose_commit_meets_a_full_disk_gives_its_run_back_and_exits_75(tmp_path, capsys, monkeypatch):
    """1d2cd70: "transient fault, back in the queue", exit 0, and the run stayed ``running`` until
    ``--stale-after`` took it. The worker holds a little space from its claim for this one write."""
    with tiny_disk(tmp_path, "2m") as disk:
        path = queued_store(disk / "s.sqlite", seed=3, max_evals=40, popsize=4)
        # call 1 scores the zero CMRT, 2 the first generation (committed), 3 the second: the disk fills meanwhile
        monkeypatch.setattr(Stub, "on_call", staticmethod(lambda n: n == 3 and fill(disk, 0)))
        monkeypatch.setattr(parallel, "Evaluator", Stub)
        assert main(["worker", "--until-idle", "--store", str(path)]) == 75
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith(f"cmrt: error: store {path}: disk full"), err
        assert "run 1 is back in the queue, its last checkpoint kept" in err, err
        (disk / "filler").unlink()
        with open_store(path, readonly=True) as store:
            run = store.run(1)
        assert run.status == "queued" and run.worker is None and run.generations == 1 and run.retries == 1


def test_a_worker_meeting_sqlite_full_gives_its_run_back(tmp_path):
    """The same path through SQLite's own limit (no mount needed): SQLITE_FULL, as a full disk gives it."""
    path = queued_store(tmp_path / "s.sqlite", seed=3, max_evals=40, popsize=4)
    with open_store(path) as store, Stub("batch") as ev:
        def after_generation(state, records, wall_s):
            pages = store.conn.execute("PRAGMA page_count").fetchone()[0]
            store.conn.execute(f"PRAGMA max_page_count = {pages}")  # no page more: the next commit is full

        t0 = time.perf_counter()
        with pytest.raises(DiskFull, match=r"disk full \(.*\); run 1 is back in the queue"):
            work(store, ev, until_idle=True, on_generation=after_generation)
        assert time.perf_counter() - t0 < 30
        run = store.run(1)
    assert run.status == "queued" and run.generations == 1 and run.retries == 1


def _hot_journal(path):
    """``path`` in rollback-journal mode with the journal of a writer killed mid-transaction beside it."""
    import subprocess

    code = ("import os, sqlite3, sys\n"
            "con = sqlite3.connect(sys.argv[1], isolation_level=None)\n"
            "con.execute('PRAGMA journal_mode = DELETE'); con.execute('PRAGMA cache_size = 1'); con.execute('BEGIN')\n"
            "for i in range(50): con.execute('UPDATE runs SET error = ?', ('x' * 3000 * (i % 3),))\n"
            "os._exit(9)\n")
    subprocess.run([sys.executable, "-c", code, str(path)], check=False)


def test_a_hot_rollback_journal_is_named_not_called_corrupted(tmp_path, capsys):
    path = queued_store(tmp_path / "s.sqlite")
    _hot_journal(path)
    journal = tmp_path / "s.sqlite-journal"
    assert journal.stat().st_size > 0
    before = (digest(path), digest(journal))
    for verb in (["runs"], ["show", "1"], ["submit", "bend", "--init", "none"]):
        assert main([*verb, "--store", str(path)]) == 2, verb
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "has a hot rollback journal" in err and "corrupted" not in err, err
    assert (digest(path), digest(journal)) == before and os.path.exists(journal)
