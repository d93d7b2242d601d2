"""Property-based fuzzing (hypothesis) of what users hand in: task files, ``--set``, command-line numbers, CMRT
JSON and sequence files.

Every generated input must end one of two ways: exit 0 with a valid result (strict JSON under ``--json``: no
NaN, no Infinity), or exit 2 with exactly one ``cmrt: error:`` line, no traceback and the store byte-identical.
Anything else - an exception escaping ``cmrt.cli.main``, two lines, a changed store - fails with hypothesis'
smallest example.

The default run is derandomized and small (well under 20 s); ``@pytest.mark.slow`` repeats each property with
many more random examples, and CMRT files against the real simulator. The verbs that simulate (``simulate``,
``sequence``) have their physics replaced by a stub in the fast part: validation happens before it.
"""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import math
import shutil
import sys
from pathlib import Path
from unittest import mock

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from cmrt.body.character import POSE_JOINTS, SIDED_JOINTS
from cmrt.body.props import PROPS
from cmrt.cli import commands as cli
from cmrt.motion.ensemble import RobustSpec
from cmrt.motion.task import DEFAULT_PARAMS
from cmrt.motion.taskfile import TASKS_DIR
from cmrt.sim import objective
from tests.input_helpers import assert_valid_json, fake_evaluation, make_store, snapshot

FAST = settings(max_examples=25, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
SLOW = settings(max_examples=600, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

# --- a workspace shared by the examples (hypothesis runs many examples in one test call) -------------------
_counter = itertools.count()


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("fuzz")
    make_store(d / "template.sqlite")
    return d


def _fresh_store(work: Path) -> Path:
    store = work / "store.sqlite"
    for suffix in ("", "-wal", "-shm"):
        Path(f"{store}{suffix}").unlink(missing_ok=True)
    shutil.copyfile(work / "template.sqlite", store)
    return store


def _file(work: Path, name: str, content: str | bytes) -> Path:
    path = work / f"{next(_counter)}_{name}"
    path.write_bytes(content if isinstance(content, bytes) else content.encode("utf-8", "surrogatepass"))
    return path


def run_cli(argv: list[str], store: Path) -> tuple[int, str, str, tuple, tuple]:
    out, err = io.StringIO(), io.StringIO()
    before = snapshot(store)
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli.main([str(a) for a in argv] + ["--store", str(store)])
    return rc, out.getvalue(), err.getvalue(), before, snapshot(store)


def check(result, json_out: bool = True) -> int:
    """Exit 0 and a valid result, or exit 2, one line, store unchanged."""
    rc, out, err, before, after = result
    event(f"exit {rc}")  # pytest --hypothesis-show-statistics: how many examples were accepted / refused
    assert "Traceback" not in err
    if rc == 0:
        errors = [line for line in err.splitlines() if not line.startswith("cmrt: warning:")]
        assert errors == [], err
        if json_out:
            assert_valid_json(out)
        return rc
    assert rc == 2, (rc, out[:300], err[:300])
    lines = err.strip("\n").split("\n")
    assert len(lines) == 1 and lines[0].startswith("cmrt: error: ") and lines[0].isprintable(), err
    assert before[0] == after[0], "the store changed on a refused input"
    return rc


@contextlib.contextmanager
def _no_physics():
    """The simulator replaced by a stub whose evaluation is all NaN (it must print as null)."""
    # the CLI imports them when a verb runs: patched where they live (``cmrt.simulate`` names the function)
    with mock.patch.object(sys.modules["cmrt.sim.simulate"], "simulate", lambda task, curve, record=True: None), \
            mock.patch.object(objective, "evaluate", lambda task, traj: fake_evaluation()):
        yield


# --- strategies ------------------------------------------------------------------------------------------
SPECIAL = [math.nan, math.inf, -math.inf, 0.0, -0.0, 1e308, -1e308, 5e-324, 1e5, 1e9, 2**63, -1]
numbers = st.one_of(
    st.floats(-100, 100),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from(SPECIAL + [0.4, 0.5, 1.0, 2.6, 3.0]),
    st.integers(-5, 100),
    st.integers(min_value=-(10**40), max_value=10**40),
)
text = st.text(max_size=12)
scalars = st.one_of(numbers, st.booleans(), text)
values = st.recursive(scalars, lambda kids: st.lists(kids, max_size=4) | st.dictionaries(text, kids, max_size=3),
                      max_leaves=8)
PARAM_NAMES = sorted({*DEFAULT_PARAMS, "via_fraction", *(k for c in PROPS.values() for k in c.PARAMS)})
param_keys = st.sampled_from(PARAM_NAMES) | text
joint_keys = st.sampled_from([*POSE_JOINTS, *(f"{j}_{s}" for j in SIDED_JOINTS for s in "rl")]) | text
pose = st.dictionaries(joint_keys, numbers | values, max_size=4) | values
pair = st.lists(numbers, min_size=0, max_size=3)
task_doc = st.fixed_dictionaries({}, optional={
    "name": text | values,
    "summary": text | values,
    "speed_param": st.sampled_from(["duration_s", "clip_s", "mass"]) | values,
    "balance_joint": st.sampled_from(["ankle", "hip", "knee", "tail", ""]) | values,
    "params": st.dictionaries(param_keys, numbers | values, max_size=6) | values,
    "param_ranges": st.dictionaries(param_keys, pair | values, max_size=2) | values,
    "start_pose_deg": pose,
    "end_pose_deg": pose,
    "via_pose_deg": pose,
    "timing": st.dictionaries(joint_keys, pair | values, max_size=3) | values,
    "prop": st.fixed_dictionaries({"kind": st.sampled_from([*PROPS, "anvil"]) | values}) | values,
    "robust": st.dictionaries(st.sampled_from(list(RobustSpec().to_table())) | text,
                              numbers | st.booleans() | st.lists(numbers, max_size=10) | values, max_size=4) | values,
    "extra": values,
})


def toml_string(v: str) -> str:
    """A TOML basic string: quotes, backslashes and control characters escaped (a lone surrogate stays: the
    file is then not UTF-8)."""
    out = []
    for c in v:
        if c in '"\\':
            out.append("\\" + c)
        elif ord(c) < 0x20 or ord(c) == 0x7F:
            out.append(f"\\u{ord(c):04X}")
        else:
            out.append(c)
    return '"' + "".join(out) + '"'


def toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return toml_string(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return "{" + ", ".join(f"{toml_string(k)} = {toml_value(x)}" for k, x in v.items()) + "}"


def to_toml(doc: dict) -> str:
    return "".join(f"{toml_string(k)} = {toml_value(v)}\n" for k, v in doc.items())


SHIPPED = [(TASKS_DIR / f).read_text() for f in ("bend.toml", "catch.toml", "push.toml", "punch.toml")]


@st.composite
def mutated_task_text(draw) -> str:
    """A shipped task file with lines replaced, dropped or added."""
    lines = draw(st.sampled_from(SHIPPED)).splitlines()
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, len(lines)))
        edit = draw(st.sampled_from(["replace", "drop", "insert", "value"]))
        if edit == "value" and i < len(lines) and "=" in lines[i]:
            key = lines[i].split("=")[0]
            lines[i] = f"{key}= {toml_value(draw(numbers | values))}"
        elif edit == "drop" and i < len(lines):
            del lines[i]
        elif edit == "replace" and i < len(lines):
            lines[i] = draw(st.text(max_size=30))
        else:
            lines.insert(i, draw(st.text(max_size=30)))
    return "\n".join(lines) + "\n"


task_text = st.one_of(mutated_task_text(), task_doc.map(to_toml), st.binary(max_size=200))


def _task_file(work, data) -> Path:
    return _file(work, "task.toml", data)


# --- properties -----------------------------------------------------------------------------------------------
def _task_file_property(work, data):
    store = _fresh_store(work)
    rc = check(run_cli(["submit", _task_file(work, data), "--init", "none", "--json"], store))
    if rc == 0:  # a task that passed validation is a task the service can run: it is in range and finite
        from cmrt.service.store import open_store
        with open_store(store) as s:
            run = s.runs()[-1]
        assert all(math.isfinite(v) for v in run.params.values())
        assert run.params["clip_s"] + run.params["tail_s"] <= 60.0


@FAST
@given(data=task_text)
def test_fuzz_task_files(work, data):
    _task_file_property(work, data)


@pytest.mark.slow
@SLOW
@given(data=task_text)
def test_fuzz_task_files_slow(work, data):
    _task_file_property(work, data)


set_values = st.one_of(
    st.floats(0.0, 3.0).map(lambda x: f"{x:.3g}"),  # plausible: often inside the parameter's range
    st.text(max_size=20),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["nan", "inf", "-inf", "1e5", "1e9", "1e400", "²", "٣", "1_0", "0x1", "", " 1 ", "9" * 5000,
                     "0.5", "2.6", "-0.0", "1e-400"]),
)


def _set_property(work, key, value):
    check(run_cli(["submit", "bend", "--set", f"{key}={value}", "--init", "none", "--json"], _fresh_store(work)))


@FAST
@given(key=param_keys, value=set_values)
def test_fuzz_set(work, key, value):
    _set_property(work, key, value)


@pytest.mark.slow
@SLOW
@given(key=param_keys, value=set_values)
def test_fuzz_set_slow(work, key, value):
    _set_property(work, key, value)


FLAGS = ["--seed", "--sigma0", "--popsize", "--max-evals", "--min-evals", "--stall-generations", "--speed", "--init"]
number_texts = st.one_of(
    set_values,
    st.integers(min_value=-(2**70), max_value=2**70).map(str),
    st.sampled_from(["0", "1", "2", "-1", str(2**63 - 1), str(2**63), "auto", "none", "1", "2", "3"]),
)


def _number_property(work, flag, value):
    argv = ["submit", "bend", f"{flag}={value}", "--json"] + ([] if flag == "--init" else ["--init", "none"])
    rc = check(run_cli(argv, _fresh_store(work)))
    if rc == 0 and flag == "--seed":
        assert 0 <= int(value) < 2**63


@FAST
@given(flag=st.sampled_from(FLAGS), value=number_texts)
def test_fuzz_command_line_numbers(work, flag, value):
    _number_property(work, flag, value)


@pytest.mark.slow
@SLOW
@given(flag=st.sampled_from(FLAGS), value=number_texts)
def test_fuzz_command_line_numbers_slow(work, flag, value):
    _number_property(work, flag, value)


knots = st.one_of(
    st.lists(st.floats(0.05, 2.55), min_size=4, max_size=4, unique=True).map(sorted),
    st.lists(numbers, max_size=6),
    values,
)
cmrt_doc = st.fixed_dictionaries(
    {},
    optional={"clip_s": st.sampled_from([2.6, 2.6, 3.0]) | numbers | values, "knot_times_s": knots,
              "values_m": st.lists(st.floats(-0.2, 0.2), min_size=4, max_size=4) | st.lists(numbers, max_size=6)
              | values, "extra": values},
)


@st.composite
def near_valid_cmrt(draw) -> dict:
    """A CMRT for the bend's 2.6 s clip, one field sometimes replaced by anything."""
    doc = {"clip_s": 2.6, "knot_times_s": sorted(draw(st.lists(st.floats(0.05, 2.55), min_size=4, max_size=4,
                                                                unique=True))),
           "values_m": draw(st.lists(st.floats(-0.3, 0.3), min_size=4, max_size=4))}
    if draw(st.booleans()):
        doc[draw(st.sampled_from(sorted(doc)))] = draw(numbers | values | st.lists(numbers, max_size=5))
    return doc


cmrt_text = st.one_of(
    near_valid_cmrt().map(lambda d: json.dumps(d)),
    cmrt_doc.map(lambda d: json.dumps(d)),  # json.dumps writes NaN and Infinity for non-finite floats
    cmrt_doc.map(lambda d: json.dumps({"cmrt": d})),
    values.map(lambda v: json.dumps(v)),
    st.text(max_size=40),
    st.binary(max_size=60),
)


def _cmrt_property(work, data, physics: bool):
    curve = _file(work, "curve.json", data)
    with contextlib.nullcontext() if physics else _no_physics():
        check(run_cli(["simulate", "bend", "--curve", curve, "--json"], _fresh_store(work)))


@FAST
@given(data=cmrt_text)
def test_fuzz_cmrt_files(work, data):
    _cmrt_property(work, data, physics=False)


@pytest.mark.slow
@settings(SLOW, max_examples=40)
@given(data=near_valid_cmrt().map(lambda d: json.dumps(d)))
def test_fuzz_cmrt_files_real_physics_slow(work, data):
    _cmrt_property(work, data, physics=True)


motion = st.fixed_dictionaries(
    {},
    optional={"task": st.sampled_from(["bend", "rise", "stand", "catch", "nope", "x.toml"]) | values,
              "speed": st.sampled_from([0.4, 0.5, 0.6]) | numbers | values,
              "start_s": st.floats(0.0, 12.0) | numbers | values, "extra": values},
)
sequence_doc = st.fixed_dictionaries(
    {},
    optional={"name": text | values, "tail_s": st.floats(0.0, 3.0) | numbers | values,
              "cop_sample_step_s": numbers | values,
              "motion": st.lists(motion, max_size=4) | values, "extra": values},
)


def _sequence_text(doc: dict) -> str:
    """``[[motion]]`` as an array of inline tables (the same document as array-of-tables syntax)."""
    return to_toml(doc)


@st.composite
def chained_sequence(draw) -> str:
    """Bend and rise alternating at plausible times, with a few numbers fuzzed."""
    n = draw(st.integers(1, 4))
    fuzz = draw(st.booleans())  # half of them exactly plausible, half with numbers from anywhere
    motions = []
    t = draw(st.floats(1.0, 2.0))
    for i in range(n):
        speed = draw(st.sampled_from([0.5, 0.5, 0.45]) | (numbers if fuzz else st.just(0.5)))
        motions.append({"task": "bend" if i % 2 == 0 else "rise", "speed": speed, "start_s": t})
        t += draw(st.floats(0.6, 3.0) | (numbers if fuzz else st.just(1.0)))
    return to_toml({"tail_s": draw(st.floats(0.0, 2.0) | (numbers if fuzz else st.just(1.0))), "motion": motions})


sequence_text = st.one_of(chained_sequence(), sequence_doc.map(_sequence_text), st.binary(max_size=100))


def _sequence_property(work, data):
    with _no_physics():
        check(run_cli(["sequence", _file(work, "seq.toml", data), "--json"], _fresh_store(work)))


@FAST
@given(data=sequence_text)
def test_fuzz_sequence_files(work, data):
    _sequence_property(work, data)


@pytest.mark.slow
@SLOW
@given(data=sequence_text)
def test_fuzz_sequence_files_slow(work, data):
    _sequence_property(work, data)
