"""Outputs never destroy: every ``--out``/``--trace`` refuses an existing file unless ``--force``, and never,
even with it, writes over a store, a TOML file (task, sequence) or a file the command reads. Real
subprocesses; every refusal is checked to leave the target's bytes as they were."""

import hashlib
import json
import subprocess
import sys

import pytest

from cmrt.errors import CmrtError
from cmrt.inputs import check_output


def run(*args):
    return subprocess.run([sys.executable, "-m", "cmrt.cli", *args], capture_output=True, text=True, timeout=300)


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def store(queued_store):
    return queued_store


def _refused(r, target, before, words):
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and words in r.stderr, r.stderr
    assert digest(target) == before


def test_export_never_writes_over_a_store(store, tmp_path):
    before = digest(store)
    other = tmp_path / "other.db"  # another store, under any name
    other.write_bytes(store.read_bytes())
    for force in ((), ("--force",)):
        r = run("export", "1", "--out", str(store), "--store", str(store), *force)
        _refused(r, store, before, "a file this command reads")
        r = run("export", "1", "--out", str(other), "--store", str(store), *force)
        _refused(r, other, before, "SQLite database")


def test_export_replaces_an_existing_file_only_with_force(store, tmp_path):
    out = tmp_path / "runs.json"
    out.write_text("mine")
    before = digest(out)
    _refused(run("export", "1", "--out", str(out), "--store", str(store)), out, before, "add --force")
    r = run("export", "1", "--out", str(out), "--store", str(store), "--force")
    assert r.returncode == 0, r.stderr
    assert isinstance(json.loads(out.read_text()), dict | list)


def test_every_verb_that_writes_a_file_says_which(store, tmp_path):
    """export, interpolate, simulate --trace (and plot, render: tests/viz) print ``wrote PATH`` on success."""
    out = tmp_path / "runs.json"
    r = run("export", "1", "--out", str(out), "--store", str(store))
    assert r.returncode == 0 and r.stdout.strip() == f"wrote {out} (json, run 1)", r
    out = tmp_path / "half.json"
    r = run("interpolate", "bend", "--speed", "0.5", "--out", str(out))
    assert r.returncode == 0 and r.stdout.strip().splitlines()[-1] == f"wrote {out}", r
    out = tmp_path / "t.npz"
    r = run("simulate", "stand", "--set", "clip_s=0.5", "--trace", str(out))
    assert r.returncode == 0 and r.stdout.strip().splitlines()[-1] == f"wrote {out}" and out.exists(), r


def test_interpolate_never_writes_over_a_task_file(tmp_path):
    task = tmp_path / "mine.toml"
    task.write_text("name = 'mine'\n")
    before = digest(task)
    for force in ((), ("--force",)):
        r = run("interpolate", "bend", "--speed", "0.5", "--out", str(task), *force)
        _refused(r, task, before, "TOML file")


def test_plot_and_render_and_trace_refuse_existing_files_before_any_work(store, tmp_path):
    png = tmp_path / "strip.png"
    png.write_bytes(b"a picture of mine")
    before = digest(png)
    _refused(run("render", "bend", "--speed", "1.2", "--out", str(png)), png, before, "add --force")
    npz = tmp_path / "t.npz"
    npz.write_bytes(b"my trace")
    _refused(run("simulate", "bend", "--speed", "1.2", "--trace", str(npz)), npz, before_npz := digest(npz),
             "add --force")
    assert digest(npz) == before_npz
    plots = tmp_path / "plots"
    plots.mkdir()
    mine = plots / "run1_cmrt.png"  # one of the three files `plot 1` writes
    mine.write_bytes(b"mine")
    _refused(run("plot", "1", "--out-dir", str(plots), "--store", str(store)), mine, digest(mine), "add --force")
    assert sorted(p.name for p in plots.iterdir()) == ["run1_cmrt.png"]  # nothing else written


def test_check_output_never_replaces_a_file_being_read(tmp_path):
    curve = tmp_path / "c.json"
    curve.write_text("{}")
    with pytest.raises(CmrtError, match="a file this command reads"):
        check_output(curve, "--out", replace=True, reading=[curve])
    assert check_output(tmp_path / "new.json", "--out", replace=False) == (tmp_path / "new.json").resolve()
