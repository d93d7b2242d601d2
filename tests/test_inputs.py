"""The validation layer (cmrt/inputs.py) and the promises built on it: strict numbers, documented ranges, input
files that cannot hang or exhaust memory, honest (atomic) outputs, JSON without NaN, escaped printing."""

from __future__ import annotations

import errno
import json
import math
import os
import sqlite3

import numpy as np
import pytest

from cmrt import inputs
from cmrt.body.props import PROPS
from cmrt.cli import commands as cli
from cmrt.errors import CmrtError, DiskFull
from cmrt.inputs import MAX_RUN_S, Range, shown
from cmrt.motion.curve import Cmrt
from cmrt.motion.sequence import load_sequence
from cmrt.motion.task import DEFAULT_PARAMS
from cmrt.motion.taskfile import available_tasks, load_task, task_from_dict
from cmrt.sim import report
from tests.input_helpers import assert_refused, assert_valid_json, call, fake_evaluation, make_store, snapshot


# --- showing values ----------------------------------------------------------------------------------------
def test_shown_escapes_and_truncates():
    assert shown("bend") == "'bend'"
    s = shown("a\nb\x1b[31m\u2028\x00")
    assert s.isprintable() and "\\n" in s and "\\x1b" in s and "\\u2028" in s and "\\x00" in s
    long = shown("x" * 1000)
    assert long.endswith("...'") and len(long) <= inputs.MAX_SHOWN + 5
    assert "digits" in shown(10**5000)  # repr would raise past Python's int-string limit
    assert shown("\udcff").isprintable()  # a lone surrogate (non-UTF-8 file name)
    assert inputs.one_line("a\nb\r\nc").isprintable() and "\n" not in inputs.one_line("a\nb")
    assert len(inputs.one_line("x" * 5000)) == inputs.MAX_MESSAGE


# --- numbers -----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("text", ["nan", "NaN", "inf", "-inf", "1e400", "²", "٣", "1_0", "0x10", "", " ", "1e",
                                  "--1", "1.2.3", "9" * 50, "1\n", "True"])
def test_strict_numbers_refuse(text):
    with pytest.raises(CmrtError, match="must be a finite number"):
        inputs.number(text, "--x")


@pytest.mark.parametrize("value", [True, False, None, [1], {"a": 1}, float("nan"), float("inf"), 10**5000, "nan"],
                         ids=["true", "false", "none", "list", "dict", "nan", "inf", "5000 digits", "text"])
def test_strict_numbers_refuse_values(value):
    with pytest.raises(CmrtError):
        inputs.number(value, "x", text=False)


def test_strict_numbers_accept():
    assert inputs.number("0.8", "x") == 0.8 and inputs.number("-1e-3", "x") == -0.001 and inputs.number(3, "x") == 3
    assert inputs.number(".5", "x") == 0.5 and inputs.number("5.", "x") == 5.0
    with pytest.raises(CmrtError, match="finite number"):  # a file's number is written as one
        inputs.number("0.8", "x", text=False)


def test_ranges_and_integers():
    r = Range(0.0, 10.0, lo_open=True, unit="s")
    assert str(r) == "(0, 10] s" and r.check("10", "x") == 10.0
    with pytest.raises(CmrtError, match=r"x must be a finite number in \(0, 10\] s, got '0'"):
        r.check("0", "x")
    assert inputs.SEED.check("0", "--seed") == 0 and inputs.SEED.check(str(2**63 - 1), "--seed") == 2**63 - 1
    for bad in ("-1", str(2**63), "1.0", "1e3", "²", "٣", "+", ""):
        with pytest.raises(CmrtError, match="--seed must be an integer"):
            inputs.SEED.check(bad, "--seed")
    assert inputs.is_run_id("12") and not inputs.is_run_id("²") and not inputs.is_run_id("+1")
    assert not inputs.is_run_id("")


def test_every_task_parameter_has_a_documented_range():
    assert set(DEFAULT_PARAMS) <= set(inputs.TASK_PARAMS)
    for cls in PROPS.values():
        assert set(cls.PARAMS) <= set(cls.LIMITS), cls.kind
        for key, value in cls.PARAMS.items():
            assert cls.LIMITS[key].contains(value), (cls.kind, key)
        for key in cls.MODEL_PARAMS:  # a model parameter never reaches MuJoCo as 0 or negative size/mass
            lo = cls.LIMITS[key].lo
            assert lo > 0 or key.endswith("_x_m"), (cls.kind, key)
    for name in available_tasks():  # every shipped task is inside the ranges
        load_task(name).validate()


def test_clip_length_is_bounded():
    stand = load_task("stand")
    assert stand.with_params(clip_s=MAX_RUN_S - 0.5).clip_s == MAX_RUN_S - 0.5
    for value in ("1e5", "1e9", "nan", "inf", "60"):
        with pytest.raises(CmrtError, match="clip_s"):
            stand.with_params(clip_s=value)


# --- input files -----------------------------------------------------------------------------------------------
def test_input_files_must_be_regular_small_utf8(tmp_path):
    fifo = tmp_path / "f.toml"
    os.mkfifo(fifo)
    for path, words in [(fifo, "not a regular file"), ("/dev/zero", "not a regular file"), (tmp_path, "directory"),
                        (tmp_path / "missing.toml", "No such file"), ("a\0b", "not a valid path")]:
        with pytest.raises(CmrtError, match=words):
            inputs.read_text(path, "task file")
    big = tmp_path / "big.toml"
    big.write_bytes(b"#" * (inputs.MAX_FILE_BYTES + 1))
    with pytest.raises(CmrtError, match="larger than"):
        inputs.read_text(big, "task file")
    latin = tmp_path / "latin.toml"
    latin.write_bytes("name = 'caf\u00e9'".encode("latin-1"))
    with pytest.raises(CmrtError, match="not UTF-8 text"):
        load_task(str(latin))


def test_nesting_and_huge_numbers_are_refused_before_python_chokes():
    with pytest.raises(CmrtError, match="nested deeper"):
        inputs.parse_toml("a = " + "[" * 100_000 + "]" * 100_000, "t")
    with pytest.raises(CmrtError, match="nested deeper"):
        inputs.parse_json("[" * 100_000, "c")
    with pytest.raises(CmrtError, match="malformed"):
        inputs.parse_toml("a = " + "9" * 5000, "t")
    with pytest.raises(CmrtError, match="not JSON"):
        inputs.parse_json("9" * 5000, "c")
    with pytest.raises(CmrtError, match="NaN is not a number"):
        inputs.parse_json('{"a": NaN}', "c")
    # brackets inside strings and comments do not count
    text = 'a = "' + "[" * 100 + '"\n# ' + "{" * 100 + "\nb = [[1], [2]]\n"
    assert inputs.parse_toml(text, "t")["b"] == [[1], [2]]
    assert inputs.parse_json('{"a": "' + "[" * 100 + '"}', "c") == {"a": "[" * 100}


def test_task_structure_is_checked():
    for raw, words in [
        ({"params": 5}, r"\[params\] must be a table"),
        ({"params": {"clip_s": "2.6"}}, "clip_s must be a finite number"),
        ({"params": {"clip_s": float("nan")}}, "clip_s must be a finite number"),
        ({"params": {"a b": 1.0}}, "parameter name"),
        ({"speed_param": ["duration_s"]}, "speed_param"),
        ({"balance_joint": "tail"}, "balance_joint"),
        ({"param_ranges": {"clip_s": ["a", "b"]}}, "param_ranges.clip_s"),
        ({"timing": {"hip": [True, False]}}, "timing.hip"),
        ({"name": 5}, "name must be a string"),
        ({"prop": {"kind": "slab"}, "params": {"slab_thickness_m": 0.0}}, "slab_thickness_m"),
        ({"robust": {"push_moments": [0.5] * 10}}, "push_moments"),
        ([1, 2], "must be a table"),
    ]:
        with pytest.raises(CmrtError, match=words):
            task_from_dict(raw, source="t.toml")


def test_sequence_numbers_are_checked(tmp_path):
    seq = tmp_path / "s.toml"
    for start, words in [("nan", "start_s"), ("inf", "start_s"), ('"soon"', "start_s"), ("-1.0", "start_s")]:
        seq.write_text(f'[[motion]]\ntask = "bend"\nspeed = 0.5\nstart_s = {start}\n')
        with pytest.raises(CmrtError, match=words):
            load_sequence(str(seq))
    seq.write_text('tail_s = nan\n[[motion]]\ntask = "bend"\nspeed = 0.5\nstart_s = 1.0\n')
    with pytest.raises(CmrtError, match="tail_s"):
        load_sequence(str(seq))


def test_cmrt_json_is_checked():
    good = {"clip_s": 2.6, "knot_times_s": [0.5, 1.0, 1.5, 2.0], "values_m": [0.0, 0.01, 0.0, 0.0]}
    assert Cmrt.from_json(json.dumps(good)).values_m[1] == 0.01
    assert Cmrt.from_json(json.dumps({"cmrt": good})).clip_s == 2.6
    for change, words in [({"clip_s": "2.6"}, "clip_s"), ({"values_m": [0, 2.0, 0, 0]}, "values_m"),
                          ({"knot_times_s": [0.5, 1.0]}, "knot_times_s"), ({"extra": 1}, "exactly")]:
        with pytest.raises(CmrtError, match=words):
            Cmrt.from_json(json.dumps({**good, **change}))


# --- outputs ---------------------------------------------------------------------------------------------
def test_atomic_output_never_leaves_half_a_file(tmp_path):
    target = tmp_path / "out.json"
    target.write_text("old")
    with pytest.raises(DiskFull, match="disk full"):  # a machine fault, not bad input: exit 75 (docs/service.md)
        with inputs.atomic_output(target, "--out") as tmp:
            tmp.write_text("partial")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert target.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]
    inputs.write_text(target, "new", "--out")
    assert target.read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]
    link = tmp_path / "link.json"
    link.symlink_to(target)  # a symlink to a regular file is written through
    inputs.write_text(link, "via link", "--out")
    assert link.is_symlink() and target.read_text() == "via link"


@pytest.mark.parametrize("path, words", [("/proc/x.json", "No such file"), ("/dev/full", "not a regular file"),
                                         ("/nonexistent/x.json", "does not exist"), ("", "not a valid path")])
def test_output_paths_are_checked_up_front(path, words):
    with pytest.raises(CmrtError, match=words):
        inputs.check_output(path, "--out")


def test_json_output_has_no_nan():
    data = {"a": float("nan"), "b": [float("inf"), 1.0, (float("-inf"),)], "c": np.float64("nan"), "d": "x"}
    assert json.loads(inputs.dumps(data)) == {"a": None, "b": [None, 1.0, [None]], "c": None, "d": "x"}
    assert_valid_json(cli.format_output(cli.Output(data, ""), True))


def test_show_and_export_json_never_print_nan(tmp_path, capsys):
    """A stored run whose JSON columns hold NaN or Infinity (``json.dumps`` writes them) is a damaged store: refused
    in one line, exit 2, before anything is printed - so no NaN ever reaches the output."""
    store = make_store(tmp_path / "s.sqlite")
    con = sqlite3.connect(store)
    con.execute("UPDATE runs SET params = ?, robustness = ? WHERE id = 1",
                (json.dumps({"clip_s": math.nan}), json.dumps({"min_cop_margin_m": math.inf})))
    con.commit()
    con.close()
    for argv in (["show", "1", "--json"], ["export", "1"]):
        r = call(capsys, [*argv, "--store", store])
        assert r.rc == 2 and r.out == "" and r.err.startswith("cmrt: error: the store is damaged")


def test_simulate_json_turns_nan_into_null(tmp_path, capsys, monkeypatch):
    # the reports (cmrt.sim.report) simulate and score: patched where the reports look them up
    monkeypatch.setattr(report, "simulate", lambda task, curve, record=True: None)
    monkeypatch.setattr(report, "evaluate", lambda task, traj: fake_evaluation())
    store = tmp_path / "s.sqlite"
    r = call(capsys, ["simulate", "bend", "--json", "--store", store])
    assert r.rc == 0 and assert_valid_json(r.out)["objective"] is None
    r = call(capsys, ["sequence", "four-poses", "--json", "--store", store])
    assert r.rc == 0 and assert_valid_json(r.out)["max_cop_error_m"] is None
    for argv in (["simulate", "bend"], ["sequence", "four-poses"]):  # the text form shows "-" for a missing number
        r = call(capsys, [*argv, "--store", store])
        assert r.rc == 0 and "objective -" in r.out
    assert not store.exists()  # neither verb touches a store


def test_printed_names_are_escaped(tmp_path, capsys):
    task = tmp_path / "evil.toml"
    task.write_text('name = "evil\\u001b[2J\\nline2"\n[params]\nduration_s = 0.5\n[end_pose_deg]\nhip = -10\n')
    store = tmp_path / "s.sqlite"
    r = call(capsys, ["submit", task, "--init", "none", "--store", store])
    assert r.rc == 0 and r.out.count("\n") == 1 and "\x1b" not in r.out and "\\x1b" in r.out
    r = call(capsys, ["runs", "--store", store])
    assert r.rc == 0 and "\x1b" not in r.out and r.out.count("\n") == 2
    r = call(capsys, ["runs", "--json", "--store", store])
    assert json.loads(r.out)[0]["task"] == "evil\x1b[2J\nline2"  # JSON keeps the value, escaped by JSON itself


def test_set_newline_is_one_escaped_line(tmp_path, capsys):
    store = make_store(tmp_path / "s.sqlite")
    before = snapshot(store)
    r = call(capsys, ["submit", "bend", "--set", "foo\nbar=1", "--store", store])
    assert_refused(r, before, snapshot(store), "foo\\nbar")
