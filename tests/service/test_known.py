"""One filter for the CMRTs known for a task (warm starts and interpolation read it)."""

import json

import numpy as np
import pytest

from cmrt.motion.curve import Cmrt
from cmrt.motion.library import library_cmrts, load_entries
from cmrt.motion.taskfile import load_task
from cmrt.service.jobs import submit
from cmrt.service.known import known_cmrts
from cmrt.service.store import open_store

BEND = load_task("bend").with_speed(0.4)


def _done(store, task, objective, success=True, robust=False):
    rid = submit(store, task, init="none")
    curve = Cmrt.from_params(np.full(8, 0.1), task.clip_s)
    with store.transaction() as conn:
        conn.execute("UPDATE runs SET status = 'done', best_success = ?, best_objective = ?, best_params = ?, "
                     "best_cmrt = ?, robust = ? WHERE id = ?",
                     (int(success), objective, json.dumps([0.1] * 8), json.dumps(curve.to_dict()),
                      json.dumps({"n": 4}) if robust else None, rid))
    return rid


def test_the_library_as_records_is_the_file():
    entries, records = load_entries(), library_cmrts()
    assert len(records) == len(entries) > 0
    for e, k in zip(entries, records, strict=True):
        assert (k.task, k.speed, k.robust, k.objective, k.source) == (
            e["task"], e["speed"], e.get("robust", False), e["objective"], "library")
        assert k.curve == Cmrt.from_dict(e["cmrt"]) and dict(k.params) == e["params"]


def test_store_first_then_library_one_mode_successes_same_clip(tmp_path):
    with open_store(tmp_path / "s.sqlite") as store:
        plain = _done(store, BEND, 0.9)
        robust = _done(store, BEND, 0.8, robust=True)
        _done(store, BEND, 0.1, success=False)  # not a success: never known
        _done(store, BEND.with_reference("yu"), 0.5)  # another reference mode
        _done(store, BEND.with_params(clip_s=3.0), 0.5)  # another clip
        known = known_cmrts(BEND, store)
        sources = [k.source for k in known]
        assert sources[:2] == [f"run {plain}", f"run {robust}"] and set(sources[2:]) == {"library"}
        assert all(k.reference == "center" and k.success and k.task == "bend" for k in known)
        assert known[0].cma_params == (0.1,) * 8 and not known[0].robust and known[1].robust
        assert [k.source for k in known_cmrts(BEND, store, robust=True, sources=("store",))] == [f"run {robust}"]
        assert len(known_cmrts(BEND.with_params(clip_s=3.0), store, sources=("store",))) == 1
        assert len(known_cmrts(BEND.with_params(clip_s=3.0), store, sources=("store",), same_clip=False)) == 3
        yu = known_cmrts(BEND.with_reference("yu"), store)
        assert yu and all(k.reference == "yu" for k in yu)
    assert all(k.source == "library" for k in known_cmrts(BEND))  # no store: the library alone


def test_resolve_curve_names_every_kind_of_known_cmrt(tmp_path):
    from cmrt.errors import CmrtError
    from cmrt.service.known import resolve_curve

    assert resolve_curve("zero", BEND) == (Cmrt.zero(BEND.clip_s), "zero")
    curve, name = resolve_curve("library", BEND)
    assert name == "library" and curve == library_cmrts()[0].curve  # the first entry: bend 0.4, plain
    store_path = tmp_path / "s.sqlite"
    with open_store(store_path) as store:
        rid = _done(store, BEND, 0.9)
    assert resolve_curve(str(rid), BEND, store_path) == (Cmrt.from_params(np.full(8, 0.1), BEND.clip_s), f"run {rid}")
    path = tmp_path / "c.json"
    path.write_text(curve.to_json())
    assert resolve_curve(str(path), BEND)[0] == curve
    for spec, words in [("nonsense", "--curve must be zero"), (str(rid), "clip"), (str(path), "clip")]:
        with pytest.raises(CmrtError, match=words):
            resolve_curve(spec, BEND.with_params(clip_s=3.0) if words == "clip" else BEND, store_path)


def test_a_one_axis_start_begins_a_two_axis_search_with_nothing_across():
    """A stored one-axis CMRT starts a search in x and y with its values across 0; a two-axis one cannot start a
    one-axis search (its second axis would be dropped silently)."""
    from cmrt.errors import CmrtError
    from cmrt.service.known import start_point

    u = tuple(np.linspace(-0.5, 0.5, 8))
    assert start_point(u, 3.1, "here", 12) == u + (0.0,) * 4
    assert start_point(u, 3.1, "here") == u and start_point(u + (0.1,) * 4, 3.1, "here", 12)[8:] == (0.1,) * 4
    with pytest.raises(CmrtError, match="here: expected 8 CMRT parameters, got 12"):
        start_point(u + (0.1,) * 4, 3.1, "here", 8)
    with pytest.raises(CmrtError, match="expected 8 or 12 CMRT parameters, got 10"):
        start_point(u + (0.1,) * 2, 3.1, "here")
