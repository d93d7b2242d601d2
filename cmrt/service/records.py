"""The records a store holds, and what every value of every column may be when cmrt reads it.

SQLite keeps any value in any column, whatever the column's declared type: a store from someone else may hold
text where a number belongs, a blob, NULL, NaN (read back as NULL), 2**63-1 or a list where a dict belongs.
Every value read from a store passes through :func:`decode` here, with its column's :class:`Column`: its type,
whether NULL is allowed, its range (counts, ids, unix times) or its choices (a run's status), and for a JSON
column the shape of what it holds. A value outside that is a one-line :class:`CmrtError` naming the run and the
column ("the store is damaged: run 3: attempt is not an integer in [0, 2147483647]"): the CLI prints it and exits
2, the dashboard answers 422, the worker fails that run with it. ``RUNS``, ``GENERATIONS`` and ``EVALUATIONS``
list every column of their table (a test holds them to the schema the migrations build).

Numbers are bounded where arithmetic or a conversion needs it: a count (``attempt``) stays far below 2**63, so
``attempt + 1`` never turns into a float; a unix time stays between 1970 and the year 3000, so it can be shown
as a date. Whether a stored task, curve or start point makes sense is checked where it is used
(``service.query.task_of``, ``service.query.stored_curve``, ``service.known.start_point``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass

from cmrt import inputs
from cmrt.errors import CmrtError
from cmrt.inputs import Range
from cmrt.modes import BACKENDS, REFERENCE_MODES

RUN_STATUSES = ("queued", "running", "done", "failed")
INT64_MAX = 2**63 - 1
#: the numbers CMA-ES searches: 8, or 12 for a CMRT in two axes (cmrt.motion.curve.N_PARAMS, N_PARAMS_TWO_AXES;
#: a test keeps them equal)
CMRT_PARAMS = (8, 12)

ID = Range(1, INT64_MAX, integer=True)  # SQLite rowids of runs
COUNT = Range(0, 2**31 - 1, integer=True)  # attempts, retries, evaluations, generations, indices
SEED = Range(0, INT64_MAX, integer=True)
UNIX_TIME = Range(0.0, 32_503_680_000.0, unit="s")  # 1970 to the year 3000: a date can be shown
DURATION = Range(0.0, math.inf, unit="s")
POSITIVE = Range(0.0, math.inf, lo_open=True)
ANY = Range()


@dataclass(frozen=True)
class Column:
    """What one column may hold: ``kind`` is "int", "real", "text", "flag" (0 or 1), "json" or "blob"; ``null``
    whether NULL is allowed; ``allowed`` a number's range; ``choices`` a text's values; ``shape`` checks (and
    returns) the value a JSON column decodes to."""

    kind: str
    null: bool = True
    allowed: Range = ANY
    choices: tuple[str, ...] = ()
    shape: Callable[[object, str], object] | None = None


def _fail(where: str, column: str, what: str) -> CmrtError:
    return CmrtError(f"the store is damaged: {where}: {column} is not {what}")


def _numbers(value: object, where: str, length: int | None = None) -> tuple[float, ...]:
    """A JSON list of finite numbers (of ``length``), as a tuple of floats."""
    if not isinstance(value, list) or (length is not None and len(value) != length):
        raise CmrtError(f"{where} is not a list of {length or 'some'} numbers")
    return tuple(inputs.number(v, where, text=False) for v in value)


def cmrt_params(value: object, where: str) -> tuple[float, ...]:
    """CMA-ES's 8 or 12 parameters (a best point, a start point, a candidate, a generation's mean)."""
    if not isinstance(value, list) or len(value) not in CMRT_PARAMS:
        raise CmrtError(f"{where} is not a list of {' or '.join(map(str, CMRT_PARAMS))} numbers")
    return _numbers(value, where)


def _table(value: object, where: str) -> dict:
    """A JSON object (a task definition, a curve, a [robust] table: checked further where it is used)."""
    if not isinstance(value, dict):
        raise CmrtError(f"{where} is not a JSON object")
    return value


CLIP_S = Range(0.0, inputs.MAX_RUN_S, lo_open=True, unit="s")


def _task_params(value: object, where: str) -> dict[str, float]:
    """A task's parameters: names to finite numbers, its clip length among them."""
    table = _table(value, where)
    params = {inputs.param_name(k, where): inputs.number(v, where, text=False) for k, v in table.items()}
    inputs.number(params.get("clip_s"), f"{where}: clip_s", CLIP_S, text=False)
    return params


ROBUSTNESS_COUNTS = ("validation_total", "validation_survived", "validation_fell")


ROBUSTNESS_MARGINS = ("min_cop_margin_m", "survived_min_cop_margin_m")  # the second since issue 44 (older: absent)


def _robustness(value: object, where: str) -> dict:
    """``cmrt.sim.validate.robustness``: three counts and the smallest CoP margins, over every clip and over the
    successes (m, or null; a run stored before issue 44 has only the first)."""
    table = _table(value, where)
    keys = {*ROBUSTNESS_COUNTS, *ROBUSTNESS_MARGINS}
    if not {*ROBUSTNESS_COUNTS, ROBUSTNESS_MARGINS[0]} <= set(table) <= keys:
        raise CmrtError(f"{where} does not have exactly {', '.join(ROBUSTNESS_COUNTS + ROBUSTNESS_MARGINS)}")
    out = {k: int(COUNT.check(table[k], where, text=False)) for k in ROBUSTNESS_COUNTS}
    for key in ROBUSTNESS_MARGINS:
        margin = table.get(key)
        out[key] = None if margin is None else inputs.number(margin, where, text=False)
    return out


def _time(null: bool = True) -> Column:
    return Column("real", null, UNIX_TIME)


def _count(null: bool = True) -> Column:
    return Column("int", null, COUNT)


def _flag() -> Column:
    return Column("flag")


def _json(shape: Callable[[object, str], object], null: bool = True) -> Column:
    return Column("json", null, shape=shape)


#: every column of ``runs``
RUNS: dict[str, Column] = {
    "id": Column("int", False, ID), "task": Column("text", False), "speed": Column("real"),
    "params": _json(_task_params, False), "task_hash": Column("text", False), "task_source": _json(_table, False),
    "seed": Column("int", False, SEED), "max_evals": _count(False), "popsize": _count(False),
    "sigma0": Column("real", False), "min_evals": _count(False), "stop_threshold": Column("real"),
    "init_run": Column("int", True, ID), "backend": Column("text", choices=BACKENDS),
    "status": Column("text", False, choices=RUN_STATUSES), "worker": Column("text"), "attempt": _count(False),
    "heartbeat_at": _time(), "created_at": _time(False), "started_at": _time(), "finished_at": _time(),
    "best_objective": Column("real"), "best_params": _json(cmrt_params), "best_fell": _flag(),
    "best_cmrt": _json(_table), "baseline_objective": Column("real"), "baseline_fell": _flag(),
    "evaluations": _count(False), "generations": _count(False), "stop_reason": Column("text"),
    "wall_s": Column("real", True, DURATION), "eval_s": Column("real", True, DURATION), "error": Column("text"),
    "best_success": _flag(), "baseline_success": _flag(), "init_source": Column("text"),
    "init_params": _json(cmrt_params), "restarts": _count(), "stall_generations": _count(),
    "robust": _json(_table), "robustness": _json(_robustness), "retries": _count(),
    "reference": Column("text", choices=REFERENCE_MODES),
}
#: every column of ``generations``
GENERATIONS: dict[str, Column] = {
    "run_id": Column("int", False, ID), "gen": _count(False), "sigma": Column("real", False, POSITIVE),
    "best_objective": Column("real", False), "gen_best_objective": Column("real", False),
    "mean": _json(cmrt_params, False), "evaluations": _count(False), "checkpoint": Column("blob", False),
    "created_at": _time(False),
}
#: every column of ``evaluations``
EVALUATIONS: dict[str, Column] = {
    "run_id": Column("int", False, ID), "gen": _count(False), "idx": _count(False),
    "params": _json(cmrt_params, False), "objective": Column("real", False), "fell": Column("flag", False),
    "seconds": Column("real", False, DURATION), "success": _flag(),
}
#: every column of ``meta`` (only the ``app`` row is read: it must say "cmrt")
META: dict[str, Column] = {"key": Column("text", False), "value": Column("text", False)}


def _value(column: Column, value: object, where: str, name: str) -> object:
    """One stored value checked against its column (NULL already handled)."""
    kind = column.kind
    if kind in ("int", "real"):
        allowed = column.allowed
        number = type(value) is int if kind == "int" else type(value) in (int, float)
        if not (number and math.isfinite(value) and allowed.contains(value)):
            bounds = f" in {allowed}" if math.isfinite(allowed.lo) or math.isfinite(allowed.hi) else ""
            raise _fail(where, name, f"{'an integer' if kind == 'int' else 'a finite number'}{bounds}")
        return value if kind == "int" else float(value)
    if kind == "flag":
        if type(value) is not int or value not in (0, 1):
            raise _fail(where, name, "0 or 1")
        return bool(value)
    if kind == "blob":
        if type(value) is not bytes:
            raise _fail(where, name, "a blob")
        return value
    if type(value) is not str:
        raise _fail(where, name, "text")
    if kind == "text":
        if column.choices and value not in column.choices:
            raise _fail(where, name, "one of " + ", ".join(column.choices))
        return value
    try:
        parsed = inputs.parse_json(value, f"{where}: {name}")
        return column.shape(parsed, f"{where}: {name}") if column.shape else parsed
    except CmrtError as exc:
        raise CmrtError(f"the store is damaged: {exc}") from None


def decode(columns: Mapping[str, Column], row: Mapping, where: str) -> dict:
    """The values of a row (every key of ``row``; an ``sqlite3.Row`` or a dict), each checked against its column
    in ``columns``: ints as int, reals as float, flags as bool, JSON decoded and shaped. One-line CmrtError
    naming ``where`` and the column otherwise."""
    out = {}
    for name in row.keys():
        value = row[name]
        column = columns.get(name)
        if column is None:
            raise _fail(where, name, "a column cmrt reads")
        if value is None:
            if not column.null:
                raise _fail(where, name, "set")
            out[name] = None
        else:
            out[name] = _value(column, value, where, name)
    return out


@dataclass(frozen=True)
class RunSpec:
    """Everything that defines a run, written in one INSERT when it is queued."""

    task: str
    speed: float | None
    params: dict[str, float]
    task_hash: str  # Task.content_hash(): the physics and the score, not the name
    task_definition: dict  # Task.to_dict(): later edits of the task file do not change a queued run
    seed: int
    max_evals: int
    popsize: int
    sigma0: float
    min_evals: int
    stop_threshold: float
    stall_generations: int
    backend: str
    init_source: str  # where the start point came from: "none", "run 12", "library (speed 0.4)"
    init_params: tuple[float, ...] | None  # the start point itself (a resume never re-resolves it)
    init_run: int | None = None  # the run id given as --init, if one was
    robust: dict | None = None  # the training ensemble's [robust] table (None: a plain run)
    reference: str = "center"  # the controller's reference mode: "center" or "yu" (cmrt.control.references)


@dataclass(frozen=True)
class Run:
    """One row of ``runs``, decoded (JSON columns as Python values, flags as bools)."""

    id: int
    task: str
    speed: float | None
    params: dict[str, float]
    task_hash: str
    task_definition: dict
    seed: int
    max_evals: int
    popsize: int
    sigma0: float
    min_evals: int
    stop_threshold: float | None
    init_run: int | None
    backend: str | None
    status: str  # one of RUN_STATUSES
    worker: str | None
    attempt: int
    heartbeat_at: float | None  # unix time of the last write of the worker holding it
    created_at: float
    started_at: float | None
    finished_at: float | None
    best_objective: float | None
    best_params: tuple[float, ...] | None
    best_fell: bool | None
    best_success: bool | None
    best_cmrt: dict | None  # Cmrt.to_dict() of the best candidate
    baseline_objective: float | None  # the zero CMRT's score
    baseline_fell: bool | None
    baseline_success: bool | None
    evaluations: int
    generations: int
    stop_reason: str | None
    wall_s: float | None
    eval_s: float | None  # summed simulation time of the evaluations
    error: str | None
    init_source: str | None
    init_params: tuple[float, ...] | None
    restarts: int | None
    stall_generations: int | None  # None: the default (OptimizeSettings)
    robust: dict | None
    robustness: dict | None  # cmrt.sim.validate.robustness of the best CMRT
    retries: int | None = None  # transient faults and take-overs so far (NULL before schema 4: none)
    reference: str = "center"  # the controller's reference mode the run was optimized with (NULL: "center")

    @classmethod
    def from_row(cls, row: Mapping) -> Run:
        """Decode a whole ``runs`` row (:data:`RUNS`); a damaged row is a CmrtError naming the run and column."""
        d = decode(RUNS, row, f"run {row['id']}")
        for name in set(RUNS) - set(d):  # a store of an older schema, read without migrating it
            if not RUNS[name].null:
                raise CmrtError(f"the store is damaged: runs has no {name}")
            d[name] = None
        d["task_definition"] = d.pop("task_source")
        d["reference"] = d["reference"] or "center"
        return cls(**d)

    def to_dict(self) -> dict:
        """The run as JSON-ready values (what ``cmrt show --json`` prints, with derived figures)."""
        return asdict(self)


@dataclass(frozen=True)
class Generation:
    """One CMA-ES generation of a run (its checkpoint blob stays in the store)."""

    gen: int
    sigma: float
    best_objective: float  # best so far in the run
    gen_best_objective: float  # best of this generation
    mean: tuple[float, ...]
    evaluations: int  # so far in the run
    created_at: float


@dataclass(frozen=True)
class StoredEvaluation:
    """One candidate's score as stored (``idx``: its place in the generation)."""

    gen: int
    idx: int
    params: tuple[float, ...]
    objective: float
    fell: bool
    success: bool | None  # None: stored by a cmrt before schema 2
    seconds: float


@dataclass(frozen=True)
class RunProgress:
    """What a run's row says after a generation."""

    evaluations: int
    generations: int
    restarts: int
    best_objective: float
    best_params: tuple[float, ...]
    best_fell: bool
    best_success: bool
    best_cmrt: dict
    wall_s: float
    eval_s_added: float  # simulation seconds of this generation's evaluations
