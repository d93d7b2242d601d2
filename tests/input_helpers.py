"""Helpers for the bad-input tests: a pre-made store, in-process ``cmrt`` calls and the exit-2 contract.

The contract every refused input must keep (docs/reference/commands.md): exit status 2, exactly one line on stderr that
starts with ``cmrt: error:`` and has no control characters, no traceback, within seconds, and the store
byte-identical (or still absent).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sqlite3
import time
from pathlib import Path

import sqlite_utils

from cmrt.cli import commands as cli
from cmrt.motion.curve import Cmrt
from cmrt.motion.taskfile import load_task
from cmrt.service.store import (
    MIGRATIONS,
    Generation,
    RunProgress,
    RunSpec,
    StoredEvaluation,
    open_store,
)
from cmrt.sim.objective import Evaluation

MAX_SECONDS = 20.0  # "within seconds", with room for a loaded 2-core machine and first imports


def make_store(path: Path) -> Path:
    """A CMRT store with one finished bend run (1, with generations and evaluations) and one queued run (2),
    written through the store's own API (no optimization needed)."""
    task = load_task("bend")
    spec = RunSpec(task=task.name, speed=task.speed, params=task.params, task_hash=task.content_hash(),
                   task_definition=task.to_dict(), seed=1, max_evals=10, popsize=10, sigma0=0.5, min_evals=0,
                   stop_threshold=task.stop_threshold, stall_generations=20, backend="batch", init_source="none",
                   init_params=None)
    with open_store(path) as s:
        rid = s.add_run(spec)
        c = s.claim("test:1", 120.0, rid)
        s.record_baseline(c, 7.7, False, False)
        best = Cmrt.zero(task.clip_s)
        s.commit_generation(
            c, RunProgress(10, 1, 0, 0.7, (0.0,) * 8, False, True, best.to_dict(), 1.0, 1.0),
            Generation(0, 0.5, 0.7, 0.7, (0.0,) * 8, 10, time.time()),
            [StoredEvaluation(0, i, (0.0,) * 8, 0.7 + i, False, True, 0.1) for i in range(10)], b"checkpoint")
        s.finish(c, "threshold", {"validation_total": 20, "validation_survived": 10, "validation_fell": 0,
                                  "min_cop_margin_m": 0.0})
        s.add_run(dataclasses.replace(spec, seed=2))
    return path


def make_old_store(path: Path, version: int = 2) -> Path:
    """A store as a cmrt of schema ``version`` left it (no runs)."""
    con = sqlite3.connect(path)
    db = sqlite_utils.Database(con)
    for step in MIGRATIONS[:version]:
        step(db)
    db["meta"].insert_all([{"key": "app", "value": "cmrt"}, {"key": "created_at", "value": "0"}])
    con.execute(f"PRAGMA user_version = {version}")
    con.commit()
    con.close()
    return path


def snapshot(path: Path) -> tuple:
    """What must not change: the store file's bytes (or its absence, or that it is a directory) and whether
    WAL/SHM files were left behind."""
    if path.is_dir():
        main = ("dir", sorted(os.listdir(path)))
    elif path.is_file():
        main = ("file", path.read_bytes())
    elif os.path.lexists(path):  # a FIFO or a device: reading it could block
        main = ("special", os.stat(path).st_mode)
    else:
        main = ("absent",)
    return main, Path(f"{path}-wal").exists(), Path(f"{path}-shm").exists()


@dataclasses.dataclass
class Result:
    rc: int
    out: str
    err: str
    seconds: float

    @property
    def err_lines(self) -> list[str]:
        return self.err.strip("\n").split("\n") if self.err.strip("\n") else []


def call(capsys, argv: list[str]) -> Result:
    """``cmrt.cli.main(argv)`` in this process, with its output captured."""
    capsys.readouterr()
    t0 = time.perf_counter()
    rc = cli.main([str(a) for a in argv])
    seconds = time.perf_counter() - t0
    captured = capsys.readouterr()
    return Result(rc, captured.out, captured.err, seconds)


def assert_refused(r: Result, before: tuple, after: tuple, words: str | None = None) -> None:
    """The exit-2 contract."""
    assert r.rc == 2, f"exit {r.rc}, stdout {r.out[:200]!r}, stderr {r.err[:300]!r}"
    lines = r.err_lines
    assert len(lines) == 1, f"{len(lines)} stderr lines: {r.err[:500]!r}"
    line = lines[0]
    assert line.startswith("cmrt: error: "), line
    assert line.isprintable(), f"control characters in {line!r}"
    assert len(line) <= 13 + 300, len(line)
    assert "Traceback" not in r.err
    assert words is None or words in line, f"{words!r} not in {line!r}"
    assert before == after, "the store changed"
    assert r.seconds < MAX_SECONDS, f"took {r.seconds:.1f} s"


def assert_valid_json(text: str):
    """Strict JSON: parsing fails on NaN/Infinity (Python's json accepts them by default)."""

    def reject(name):
        raise AssertionError(f"JSON output contains {name}")

    return json.loads(text, parse_constant=reject)


def fake_evaluation() -> Evaluation:
    """An Evaluation whose numbers are NaN (they must print as null) - for verbs whose physics a fast test
    replaces."""
    values = {}
    for f in dataclasses.fields(Evaluation):
        values[f.name] = False if f.type in ("bool", "bool | None") else math.nan
    return Evaluation(**values)
