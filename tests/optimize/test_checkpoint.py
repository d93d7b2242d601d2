"""The optimizer checkpoint (cmrt.optimize.checkpoint): bit-identical resume, and nothing in a store runs."""

import base64
import copy
import functools
import os
import pickle
import sqlite3
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from cmrt.errors import CmrtError
from cmrt.motion.taskfile import load_task
from cmrt.optimize.checkpoint import MAGIC, InvalidCheckpoint, pack_document, unpack_document
from cmrt.optimize.driver import (
    CmaState,
    OptimizeSettings,
    best_cmrt,
    checkpoint,
    new_state,
    restart_if_stalled,
    step,
    stop_reason,
)
from cmrt.optimize.parallel import Evaluator
from cmrt.service.jobs import claim, submit, work
from cmrt.service.store import Generation, RunProgress, StoredEvaluation, open_store
from cmrt.sim.objective import EvalRecord
from tests.optimize.toy_objectives import rugged, sphere
from tests.service_helpers import spawn_worker

TASK = load_task("bend").with_speed(0.4)
RUGGED = OptimizeSettings(seed=4, max_evals=2000, stall_generations=3, min_evals=0, stop_threshold=10.0)


def drive(state, settings, n_gen, objective=rugged):
    """``n_gen`` generations as the worker runs them; returns every asked population and objective."""
    trace = []
    for _ in range(n_gen):
        if stop_reason(state, settings) is not None:
            break
        xs, records = step(state, objective)
        restart_if_stalled(state, settings)
        trace.append((np.array(xs), [r.objective for r in records], state.restarts))
    return trace


def snapshots():
    """(name, settings, state) at the points a checkpoint is written: fresh, warm start, mid-run,
    right after an IPOP restart, after several restarts."""
    yield "fresh", RUGGED, new_state(RUGGED)
    warm = OptimizeSettings(seed=1, x0=tuple(np.linspace(-0.3, 0.4, 8)))
    yield "warm start", warm, new_state(warm)
    mirrored = OptimizeSettings(seed=3, popsize=5)  # popsize < 6: pycma samples mirrored pairs
    state = new_state(mirrored)
    drive(state, mirrored, 4, sphere)
    yield "mirrored", mirrored, state
    state = new_state(RUGGED)
    drive(state, RUGGED, 3)
    yield "mid-run", RUGGED, state
    state = new_state(RUGGED)
    while state.restarts == 0:
        drive(state, RUGGED, 1)
    yield "just restarted", RUGGED, state
    drive(state, RUGGED, 15)
    assert state.restarts >= 2
    yield "after restarts", RUGGED, state
    two = OptimizeSettings(seed=2, max_evals=2000, stall_generations=3, min_evals=0, stop_threshold=10.0,
                           n_params=12)  # a CMRT in x and y
    state = new_state(two)
    drive(state, two, 5)
    yield "two axes", two, state


# --- bit-identical resume ------------------------------------------------------------------------------

@pytest.mark.parametrize("name", [n for n, _, _ in snapshots()])
def test_round_trip_continues_bit_identically(name):
    settings, state = next((s, st) for n, s, st in snapshots() if n == name)
    blob = state.dumps()
    assert blob.startswith(MAGIC)
    resumed = CmaState.loads(blob, settings, run_id=1)
    assert resumed.dumps() == blob  # the rebuilt object graph writes the very same document
    straight = drive(state, settings, 12)
    again = drive(resumed, settings, 12)
    assert len(straight) == len(again) >= 5  # the last snapshot reaches its stop
    for (xs_a, f_a, r_a), (xs_b, f_b, r_b) in zip(straight, again, strict=True):
        assert xs_a.tobytes() == xs_b.tobytes() and f_a == f_b and r_a == r_b
    for attr in ("mean", "C", "pc", "D", "B"):
        assert getattr(state.es, attr).tobytes() == getattr(resumed.es, attr).tobytes(), attr
    assert state.es.sigma == resumed.es.sigma and state.best_history == resumed.best_history
    assert state.randn.rng.bit_generator.state == resumed.randn.rng.bit_generator.state


def test_a_checkpoint_resumes_only_a_search_of_its_own_dimension():
    """A 12-parameter search (a CMRT in x and y) resumes as one; loaded for an 8-parameter run it is refused, as
    is a start point of the wrong length."""
    two = OptimizeSettings(seed=2, n_params=12)
    state = new_state(two)
    drive(state, two, 2, sphere)
    assert state.es.N == 12 and state.best_x.shape == (12,)
    CmaState.loads(state.dumps(), two, run_id=1)
    with pytest.raises(InvalidCheckpoint, match="dimension"):
        CmaState.loads(state.dumps(), OptimizeSettings(seed=2), run_id=1)
    with pytest.raises(CmrtError, match="a start point of 8 parameters for a CMRT of 12"):
        OptimizeSettings(n_params=12, x0=(0.0,) * 8)
    with pytest.raises(CmrtError, match="n_params must be 8 or 12"):
        OptimizeSettings(n_params=16)


def test_resume_across_restarts_matches_pickle():
    """The old (pickle) round trip and the new one continue identically, restart after restart."""
    state = new_state(RUGGED)
    drive(state, RUGGED, 5)
    via_pickle = pickle.loads(pickle.dumps(state))  # the reference the format replaces (our own object)
    via_doc = CmaState.loads(state.dumps(), RUGGED)
    a, b = drive(via_pickle, RUGGED, 30), drive(via_doc, RUGGED, 30)
    assert via_doc.restarts >= 2
    assert all(x[0].tobytes() == y[0].tobytes() and x[1] == y[1] for x, y in zip(a, b, strict=True))


def test_one_generator_after_loading():
    """Restarts must draw from the generator the ES draws from: identity and cycles survive."""
    state = new_state(RUGGED)
    drive(state, RUGGED, 2)
    loaded = CmaState.loads(state.dumps())
    es = loaded.es
    assert loaded.randn is es.opts["randn"] is es.sm.randn is es.inputargs["inopts"]["randn"]
    assert es.logger.es is es and es.adapt_sigma._es_opts is es.opts
    loaded.randn.rng.standard_normal(3)  # drawing through one reference advances all of them
    assert es.sm.randn.rng.bit_generator.state == loaded.randn.rng.bit_generator.state
    assert es.opts["randn"] is not state.randn  # a copy, not the live object


OLD_CHECKPOINT = Path(__file__).resolve().parents[1] / "data" / "checkpoint_flat_modules.bin"


def test_a_checkpoint_naming_the_old_module_paths_resumes():
    """Runs in flight when cmrt's modules moved into layer packages (issue 28) hold checkpoints that name
    ``cmrt.optimize:CmaState`` and ``cmrt.optimize:_Randn``; they resume at the classes' new home, exactly
    as a checkpoint with the new names, and are written back with the new names."""
    state = new_state(RUGGED)
    drive(state, RUGGED, 3)
    doc = unpack_document(state.dumps())
    for new in ("cmrt.optimize.driver:CmaState", "cmrt.optimize.driver:_Randn"):
        rename(new, new.replace("cmrt.optimize.driver:", "cmrt.optimize:"))(doc, None)
    old_blob = pack_document(doc)
    assert b"cmrt.optimize.driver" not in zlib.decompress(old_blob[len(MAGIC):])
    resumed = CmaState.loads(old_blob, RUGGED, run_id=1)
    assert resumed.dumps() == state.dumps()  # written back with the current names, otherwise the same
    a, b = drive(state, RUGGED, 10), drive(resumed, RUGGED, 10)
    assert all(x[0].tobytes() == y[0].tobytes() and x[1] == y[1] for x, y in zip(a, b, strict=True))


@pytest.mark.skipif(checkpoint.cma.__version__ != "4.5.0", reason="the stored blob was written with pycma 4.5.0")
def test_a_checkpoint_written_by_the_flat_layout_resumes():
    """``tests/data/checkpoint_flat_modules.bin``: written by cmrt at 06b4c87 (flat ``cmrt/optimize.py``) after
    three generations of ``rugged`` from ``new_state(RUGGED)``, on another machine (an AMD EPYC): it resumes
    where today's code is after those generations, to a relative 1e-9 (another CPU's libm and BLAS round
    differently; the bit-identical resume on one machine is the test above), and goes on from there."""
    blob = OLD_CHECKPOINT.read_bytes()
    assert b"cmrt.optimize:CmaState" in zlib.decompress(blob[len(MAGIC):])
    resumed = CmaState.loads(blob, RUGGED, run_id=1)
    assert b"cmrt.optimize.driver:CmaState" in zlib.decompress(resumed.dumps()[len(MAGIC):])
    state = new_state(RUGGED)
    drive(state, RUGGED, 3)
    assert (resumed.generation, resumed.evaluations) == (state.generation, state.evaluations)
    for attr in ("mean", "C", "pc", "D", "B"):  # (pycma's timers differ: the blob is not the same bytes)
        np.testing.assert_allclose(getattr(resumed.es, attr), getattr(state.es, attr), rtol=1e-9, atol=1e-12,
                                   err_msg=attr)
    again = CmaState.loads(resumed.dumps(), RUGGED, run_id=1)  # written back with the new names: the same state
    a, b = drive(resumed, RUGGED, 10), drive(again, RUGGED, 10)
    assert all(x[0].tobytes() == y[0].tobytes() and x[1] == y[1] for x, y in zip(a, b, strict=True))


def test_moved_names_reach_only_allowlisted_classes():
    """The alias table renames module paths; it does not widen the allowlist."""
    assert checkpoint.current_name("cmrt.optimize:CmaState") == "cmrt.optimize.driver:CmaState"
    assert checkpoint.current_name("cmrt.optimize.driver:_Randn") == "cmrt.optimize.driver:_Randn"
    doc = valid_doc()
    rename("cmrt.optimize.driver:_Randn", "cmrt.optimize:OptimizeSettings")(doc, None)
    with pytest.raises(InvalidCheckpoint, match="is not allowlisted"):
        CmaState.loads(pack_document(doc))


def test_the_allowlist_is_what_pycma_really_holds():
    """Every allowlisted class occurs in a real state, and a real state needs nothing else
    (``dumps`` raises TypeError on anything outside the allowlists: a bug, caught here)."""
    used, functions = set(), set()

    def walk(node):
        if isinstance(node, list):
            if node and node[0] == "O":
                used.add(node[2])
            if node and node[0] == "F":
                functions.add(node[1])
            for n in node:
                walk(n)

    for _, _, state in snapshots():
        walk(unpack_document(state.dumps())["root"])
    allowed = {checkpoint._name(c) for c in checkpoint.PYCMA_CLASSES} | {"cmrt.optimize.driver:CmaState",
                                                                         "cmrt.optimize.driver:_Randn"}
    assert used == allowed
    assert functions == set(checkpoint.FUNCTIONS)
    for cls in checkpoint.PYCMA_CLASSES:  # the rebuild (builtin __new__ + __dict__) fits every one of them
        assert not any(vars(c).get("__slots__") or "__new__" in vars(c) for c in cls.__mro__
                       if c not in (object, dict, list)), cls


def test_writing_anything_unvetted_fails_loudly():
    state = new_state(RUGGED)
    state.es.callbackstop = (os.system,)
    with pytest.raises(TypeError, match="callbackstop.*not allowlisted"):
        state.dumps()
    state = new_state(RUGGED)
    state.best_history = [np.array(["a"])]
    with pytest.raises(TypeError, match="dtype"):
        state.dumps()


# --- refusing: old pickles, crafted documents ----------------------------------------------------------

class Boom:
    """A pickle payload: unpickling it runs a shell command that creates ``marker``."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return os.system, (f"touch '{self.marker}'",)


def test_the_payload_is_live(tmp_path):
    """Control: the payload the store tests plant does run under pickle - and not under CmaState.loads."""
    marker = tmp_path / "pwned"
    blob = pickle.dumps(Boom(marker))
    with pytest.raises(InvalidCheckpoint, match="pickle written by an older cmrt"):
        CmaState.loads(blob)
    assert not marker.exists()
    pickle.loads(blob)
    assert marker.exists()


def valid_doc(settings=RUGGED):
    state = new_state(settings)
    drive(state, settings, 2)
    return unpack_document(state.dumps())


def nodes(node, tag=None, name=None):
    """Every tagged node (optionally with ``tag``, and for objects/functions ``name``) in a document."""
    if isinstance(node, list):
        if node and isinstance(node[0], str) and (tag is None or node[0] == tag) and (
                name is None or name in node[1:4]):
            yield node
        for n in node:
            yield from nodes(n, tag, name)


def obj(doc, name):
    return next(nodes(doc["root"], "O", name))


def attr(o, key):
    return next(pair for pair in o[3] if pair[0] == key)


def option(doc, key):
    return next(pair for pair in obj(doc, "cma.options_parameters:CMAOptions")[4] if pair[0] == key)


def rename(old, new):
    def craft(doc, marker):
        for node in nodes(doc["root"], name=old):
            node[node.index(old)] = new
    return craft


def set_option(key, value):
    def craft(doc, marker):
        option(doc, key)[1] = value.replace("{marker}", str(marker)) if isinstance(value, str) else value
    return craft


def set_array(**fields):
    def craft(doc, marker):
        node = attr(obj(doc, "cma.evolution_strategy:CMAEvolutionStrategy"), "mean")[1]
        for key, value in fields.items():
            node[{"dtype": 2, "shape": 3, "order": 4, "data": 5}[key]] = value
    return craft


def add_attr(cls, key, value):
    def craft(doc, marker):
        obj(doc, cls)[3].append([key, value])
    return craft


def set_header(key, value):
    def craft(doc, marker):
        doc[key] = value
    return craft


def reference_ahead(doc, marker):
    attr(obj(doc, "cmrt.optimize.driver:CmaState"), "randn")[1] = ["R", 10**6]


def renumber(doc):
    """Number the objects of a edited document again, in the order the reader meets them."""
    new, count = {}, iter(range(10**9))

    def register(node):
        new[node[1]] = node[1] = next(count)

    def visit(node):
        if not isinstance(node, list):
            return
        tag = node[0]
        if tag == "R":
            node[1] = new[node[1]]
        elif tag == "T":
            for v in node[1]:
                visit(v)
        elif tag in ("L", "D"):
            register(node)
            for v in node[2]:
                visit(v[1] if tag == "D" else v)
        elif tag == "A":
            register(node)
        elif tag == "G":
            visit(node[3])
            register(node)
        elif tag == "O":
            register(node)
            for _, v in node[3]:
                visit(v)
            is_dict = issubclass(next(c for c in checkpoint.PYCMA_CLASSES + (dict,)
                                      if checkpoint._name(c) == node[2] or c is dict), dict)
            for v in node[4] or ():
                visit(v[1] if is_dict else v)

    visit(doc["root"])


def second_generator(doc, marker):
    """The ES's sampler draws from a generator of its own (a copy of the state's)."""
    randn = copy.deepcopy(obj(doc, "cmrt.optimize.driver:_Randn"))
    for node in [randn, *nodes(randn[3], "G"), *nodes(randn[3], "D")]:
        node[1] = ("copy", node[1])  # ids of its own until renumbered
    attr(obj(doc, "cma.sampler:GaussFullSampler"), "randn")[1] = randn
    renumber(doc)


CODE = "__import__('os').system('touch {marker}')"
CRAFTED = {  # case: (edit of a valid document, why it must be refused)
    "class os._wrap_close": (rename("cmrt.optimize.driver:_Randn", "os:_wrap_close"), "class 'os:_wrap_close' is not"),
    "class subprocess.Popen": (rename("cma.utilities.utils:BlancClass", "subprocess:Popen"), "class 'subprocess:P"),
    "class builtins.eval": (rename("cma.boundary_handler:BoundNone", "builtins:eval"), "class 'builtins:eval' is not"),
    "function os.system": (rename("cma.evolution_strategy:_pass", "os:system"), "function 'os:system' is not"),
    "function builtins.eval": (rename("numpy.linalg:eigh", "builtins:eval"), "function 'builtins:eval' is not"),
    "option with code (tolfun)": (set_option("tolfun", CODE), "options differ from the run's: tolfun"),
    "option with code (maxiter)": (set_option("maxiter", "3 * N"), "options differ from the run's: maxiter"),
    "signals file switched on": (set_option("signals_filename", "{marker}.in"), "differ from the run's: signals_f"),
    "logging switched on": (set_option("verb_log", 1), "options differ from the run's: verb_log"),
    "function swapped in options": (set_option("CMA_eigenmethod", ["F", "cma.options_parameters:is_feasible"]),
                                    "options differ from the run's: CMA_eigenmethod"),
    "huge array shape": (set_array(shape=[10**12]), "array of shape [1000000000000] and dtype <f8 does not match"),
    "negative array shape": (set_array(shape=[-8]), "bad array shape"),
    "object array": (set_array(dtype="|O"), "array dtype '|O' is not allowlisted"),
    "string array": (set_array(dtype="<U8"), "array dtype '<U8' is not allowlisted"),
    "array not base64": (set_array(data="$$$$"), "array data is not base64"),
    "attribute shadowing a method": (add_attr("cma.evolution_strategy:CMAEvolutionStrategy", "tell",
                                              ["F", "numpy.linalg:eigh"]), "attribute 'tell' would shadow a method"),
    "dunder attribute": (add_attr("cmrt.optimize.driver:_Randn", "__class__", ["F", "numpy.linalg:eigh"]),
                         "attribute '__class__'"),
    "unknown node": (add_attr("cmrt.optimize.driver:CmaState", "extra", ["X", 1]), "unknown node"),
    "extra state field": (add_attr("cmrt.optimize.driver:CmaState", "extra", 1), "CmaState fields differ"),
    "reference ahead": (reference_ahead, "reference to unknown object"),
    "second generator": (second_generator, "not exactly one _Randn"),
    "other pycma version": (set_header("pycma", "3.0.0"), "written with pycma '3.0.0'"),
    "other format": (set_header("format", 2), "format 2"),
    "root not a state": (set_header("root", ["L", 0, []]), "the root is not a CmaState"),
}


@pytest.mark.parametrize("case", list(CRAFTED))
def test_crafted_documents_are_refused(case, tmp_path):
    marker = tmp_path / "pwned"
    doc = valid_doc()
    craft, why = CRAFTED[case]
    craft(doc, marker)
    with pytest.raises(InvalidCheckpoint, match="^checkpoint of run 7 is not a valid cmrt checkpoint: ") as exc:
        CmaState.loads(pack_document(doc), RUGGED, run_id=7)
    assert why in str(exc.value) and "\n" not in str(exc.value) and isinstance(exc.value, CmrtError)
    assert not marker.exists() and not (tmp_path / "pwned.in").exists()


def test_options_are_checked_against_the_runs_settings():
    state = new_state(RUGGED)
    while state.restarts == 0:
        drive(state, RUGGED, 1)
    blob = state.dumps()
    assert CmaState.loads(blob, RUGGED).es.popsize == 20
    with pytest.raises(InvalidCheckpoint, match="population 20 in the large regime after 1 large restarts, "
                       "the run.s settings give 30"):
        CmaState.loads(blob, OptimizeSettings(**{**RUGGED.__dict__, "popsize": 15}))


def blobs():
    good = new_state(RUGGED).dumps()
    body = zlib.decompress(good[len(MAGIC):])
    yield "empty", b""
    yield "wrong magic", b"CMRT-CKPT-9\n" + good[len(MAGIC):]
    yield "json without magic", body
    yield "truncated", good[: len(good) // 2]
    yield "garbled", good[:40] + bytes(b ^ 0x5A for b in good[40:80]) + good[80:]
    yield "trailing bytes", good + b"\x00junk"
    yield "not json", MAGIC + zlib.compress(b"{'root': 1}")
    yield "not utf-8", MAGIC + zlib.compress(b"\xff\xfe{}")
    yield "huge int", MAGIC + zlib.compress(b'{"format": 1, "pycma": "x", "root": ' + b"9" * 10_000 + b"}")
    yield "zip bomb", MAGIC + zlib.compress(b" " * (checkpoint.MAX_DOCUMENT_BYTES + 1), 9)
    yield "pickle protocol 2", pickle.dumps(new_state(RUGGED), protocol=2)
    for depth in (100, 100_000):  # past MAX_DEPTH, past what json itself can nest
        root = '["T",[' * depth + "]]" * depth
        yield f"nested {depth} deep", MAGIC + zlib.compress(
            f'{{"format":1,"pycma":"{checkpoint._CMA_VERSION}","root":{root}}}'.encode())


@functools.cache
def blob_table() -> dict[str, bytes]:
    """The bad blobs, built once (the zip bomb alone takes half a second to compress)."""
    return dict(blobs())


@pytest.mark.parametrize("case", list(blob_table()))
def test_bad_bytes_are_refused(case):
    blob = blob_table()[case]
    with pytest.raises(InvalidCheckpoint, match="^checkpoint of run 3 is not a valid cmrt checkpoint: ") as exc:
        CmaState.loads(blob, run_id=3)
    assert "\n" not in str(exc.value)


def test_array_bytes_decode_exactly():
    """The ``A`` node carries the bytes: dtype, shape and memory order survive (as with pickle)."""
    doc = valid_doc()
    arrays = list(nodes(doc["root"], "A"))
    assert any(a[4] == "F" for a in arrays)  # pycma's eigenbasis is Fortran-ordered
    a = arrays[0]
    raw = base64.b64decode(a[5])
    assert len(raw) == int(np.prod(a[3])) * np.dtype(a[2]).itemsize


# --- the store: a worker resuming a planted checkpoint -------------------------------------------------

def commit_fake_generation(store, c, state):
    """One real optimizer generation (scored by a toy objective) committed as the worker commits it."""
    xs, records = step(state, sphere)
    store.commit_generation(
        c,
        RunProgress(evaluations=state.evaluations, generations=state.generation, restarts=state.restarts,
                    best_objective=state.best_objective, best_params=tuple(state.best_x.tolist()),
                    best_fell=state.best_fell, best_success=state.best_success,
                    best_cmrt=best_cmrt(state, TASK.clip_s).to_dict(), wall_s=1.0, eval_s_added=0.5),
        Generation(gen=state.generation - 1, sigma=float(state.es.sigma), best_objective=state.best_objective,
                   gen_best_objective=min(r.objective for r in records), mean=tuple(map(float, state.es.mean)),
                   evaluations=state.evaluations, created_at=time.time()),
        [StoredEvaluation(gen=state.generation - 1, idx=i, params=tuple(x.tolist()), objective=r.objective,
                          fell=r.fell, success=r.success, seconds=0.1)
         for i, (x, r) in enumerate(zip(xs, records, strict=True))],
        state.dumps(),
    )


def planted_store(path, blob):
    """Run A (orphaned: its worker's heartbeat is old) whose last checkpoint is ``blob``, and run B, alive
    in another worker. Returns (A, B)."""
    with open_store(path) as store:
        a = submit(store, TASK, seed=1, max_evals=40, popsize=5, init="none")
        b = submit(store, TASK, seed=2, max_evals=40, popsize=5, init="none")
        for rid, worker in ((a, "dead:1"), (b, "alive:2")):
            c = claim(store, worker, run_id=rid)
            state = new_state(OptimizeSettings(seed=rid, popsize=5, max_evals=40))
            commit_fake_generation(store, c, state)
            commit_fake_generation(store, c, state)
        with store.transaction() as conn:
            conn.execute("UPDATE generations SET checkpoint = ? WHERE run_id = ? AND gen = 1", (blob, a))
            conn.execute("UPDATE runs SET heartbeat_at = 0 WHERE id = ?", (a,))
    return a, b


def dump_store(path):
    with sqlite3.connect(path) as con:
        con.row_factory = sqlite3.Row
        return {table: [dict(r) for r in con.execute(f"SELECT * FROM {table} ORDER BY 1, 2")]
                for table in ("runs", "generations", "evaluations")}


def assert_refused_and_nothing_else_changed(path, before, a, b, marker):
    after = dump_store(path)
    assert not marker.exists()
    assert after["generations"] == before["generations"] and after["evaluations"] == before["evaluations"]
    run_a = next(r for r in after["runs"] if r["id"] == a)
    assert run_a["status"] == "failed" and run_a["attempt"] == 2
    error = run_a["error"]
    assert error.startswith(f"checkpoint of run {a} is not a valid cmrt checkpoint: ") and "\n" not in error
    assert run_a["baseline_objective"] is None  # refused before anything was simulated
    old_a = next(r for r in before["runs"] if r["id"] == a)
    changed = {k for k in run_a if run_a[k] != old_a[k]}
    assert changed <= {"status", "error", "finished_at", "attempt", "worker", "heartbeat_at", "retries"}
    assert [r for r in after["runs"] if r["id"] != a] == [r for r in before["runs"] if r["id"] != a]
    return error


RUN_A = OptimizeSettings(seed=1, popsize=5, max_evals=40)  # as planted_store submits run A


def _crafted(craft, marker):
    doc = valid_doc(RUN_A)
    craft(doc, marker)
    return pack_document(doc)


PLANTED = {  # what is planted, and why it is refused
    "pickle payload": (lambda marker: pickle.dumps(Boom(marker)), "pickle written by an older cmrt"),
    "class subprocess.Popen": (lambda marker: _crafted(rename("cma.utilities.utils:BlancClass", "subprocess:Popen"),
                                                       marker), "class 'subprocess:Popen' is not allowlisted"),
    "option with code": (lambda marker: _crafted(set_option("tolfun", CODE), marker),
                         "CMA-ES options differ from the run's: tolfun"),
}


@pytest.mark.parametrize("case", list(PLANTED))
def test_a_worker_resuming_a_planted_checkpoint_runs_nothing(case, tmp_path):
    marker, path = tmp_path / "pwned", tmp_path / "s.sqlite"
    plant, why = PLANTED[case]
    a, b = planted_store(path, plant(marker))
    before = dump_store(path)
    with open_store(path) as store:
        assert work(store, Evaluator("serial"), once=True, stale_after_s=60) == []
    assert why in assert_refused_and_nothing_else_changed(path, before, a, b, marker)


@pytest.mark.slow  # a real `cmrt worker` process
def test_a_real_worker_process_refuses_a_pickle_checkpoint(tmp_path):
    marker, path = tmp_path / "pwned", tmp_path / "s.sqlite"
    a, b = planted_store(path, pickle.dumps(Boom(marker)))
    before = dump_store(path)
    worker = spawn_worker(path, "--once", "--stale-after", "60", backend="serial")
    _, err = worker.communicate(timeout=300)
    assert worker.returncode == 0, err
    assert_refused_and_nothing_else_changed(path, before, a, b, marker)


_LEAN_IMPORT = """
import sys
import cmrt.optimize.driver
lean = "matplotlib" not in sys.modules and "scipy.stats" not in sys.modules
import matplotlib.pyplot, scipy.stats  # importable as usual afterwards
from cmrt.optimize.checkpoint import cma
es = cma.CMAEvolutionStrategy([0.0] * 8, 0.5, {"verbose": -9, "seed": 3})
print(lean, cma.s._pyplot is None, es.ask()[0][0])
"""


@pytest.mark.slow  # a fresh process
def test_pycma_is_imported_without_matplotlib_and_scipy_stats():
    """``import_cma`` keeps matplotlib and scipy.stats (1.5 s) out of pycma's import; both import as usual
    afterwards and CMA-ES samples exactly as with the plain import. A user's matplotlib, imported first, is
    left alone (pycma then has its plotting)."""
    lean = subprocess.run([sys.executable, "-c", _LEAN_IMPORT], capture_output=True, text=True, check=True)
    plain = subprocess.run([sys.executable, "-c", "import matplotlib.pyplot\n" + _LEAN_IMPORT],
                           capture_output=True, text=True, check=True)
    got_lean, no_pyplot, x_lean = lean.stdout.split()
    got_plain, no_pyplot_plain, x_plain = plain.stdout.split()
    assert (got_lean, no_pyplot) == ("True", "True")
    assert (got_plain, no_pyplot_plain) == ("False", "False")
    assert x_lean == x_plain


def test_a_checkpoint_carries_no_machine_paths_or_wall_clock_times(tmp_path, monkeypatch):
    """A shared store must not tell where (the worker's working directory) or when its workers ran."""
    import re
    import time
    import zlib

    from cmrt.optimize.driver import step

    monkeypatch.chdir(tmp_path)
    state = new_state(OptimizeSettings(seed=3))
    step(state, lambda xs: [EvalRecord(1.0 + i, False, 0.0) for i, _ in enumerate(xs)])
    text = zlib.decompress(state.dumps()[len(b"CMRT-CKPT-1\n"):]).decode()
    assert str(tmp_path) not in text and "outcmaes/" in text
    epoch = str(int(time.time()))[:4]  # the leading digits of any wall-clock time written now
    assert not re.search(rf"\b{epoch}\d{{6}}\.\d+", text)
    assert state.es.logger.name_prefix.startswith(str(tmp_path))  # the live state is left as it was


# --- checkpoints that pass the structure checks but imply unbounded work (issue 27) --------------------

def _forge(mutate):
    """A real mid-run state of a population-4 run, changed by ``mutate(state)``, as a checkpoint blob."""
    settings = OptimizeSettings(seed=2, popsize=4, stall_generations=3, max_evals=500)
    state = new_state(settings)
    drive(state, settings, 6, sphere)
    mutate(state)
    return settings, state.dumps()


def _set(path, value):
    def mutate(state):
        obj = state.es
        *parents, last = path.split(".")
        for name in parents:
            obj = getattr(obj, name)
        setattr(obj, last, value(state) if callable(value) else value)
    return mutate


FORGED = {
    # each of these loaded and then exhausted memory or time in pycma (the red-team findings)
    "stagnation exponent 10**18": (_set("_stoptolxstagnation.time_delta_expo", 10**18), "time_delta_expo"),
    "6,000 injected solutions": (_set("pop_injection_solutions", lambda s: [s.es.mean.copy()] * 6000),
                                 "pop_injection_solutions has 6000 entries"),
    "300,000 fitness-history entries": (_set("fit.hist", [1.0] * 300_000), "fit.hist has 300000"),
    "history past pycma's own cap": (_set("fit.histbest", [1.0] * 20_001), "fit.histbest has 20001"),
    "a population-40 weight vector": (_set("sp.weights", lambda s: type(s.es.sp.weights)(40)),
                                      "recombination weights|sp.weights"),
    "damping changed": (_set("adapt_sigma.damps", 1e-9), "adapt_sigma.damps"),
    "iteration counter past the run's": (_set("countiter", 10**6), "counters exceed"),
    "a counter past 2**40": (_set("number_of_solutions_asked", 2**62), "out of range"),
}


@pytest.mark.parametrize("case", list(FORGED))
def test_checkpoints_implying_unbounded_work_are_refused(case):
    mutate, why = FORGED[case]
    settings, blob = _forge(mutate)
    t0 = time.perf_counter()
    with pytest.raises(InvalidCheckpoint, match=why):
        CmaState.loads(blob, settings)
    assert time.perf_counter() - t0 < 5.0  # refused, not worked through


def test_the_bounds_admit_every_real_checkpoint():
    """The bounds are not tighter than pycma: histories at pycma's own cap (2e4 entries, ~1e5 generations
    of a population-2 run) and a population-100 run after a large restart load."""
    settings, blob = _forge(_set("fit.histbest", [1.0] * 20_000))
    CmaState.loads(blob, settings)
    wide = OptimizeSettings(seed=6, popsize=100, stall_generations=2, max_evals=10**5, min_evals=0)
    state = new_state(wide)
    drive(state, wide, 8, rugged)
    assert state.large_restarts >= 1
    CmaState.loads(state.dumps(), wide)
