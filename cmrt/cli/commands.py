"""The ``cmrt`` command: a thin shell over the Python API.

Each verb is one :class:`Command` (its arguments next to its action); an action calls the
API and returns an :class:`Output`, which one formatter prints as JSON (``--json``) or
text. Logic a script would want too lives in the API, not here.

Bad input (unknown task, bad value, unreadable file) prints one line,
``cmrt: error: ...``, and exits with status 2 - never a traceback. Every argument is checked
(``cmrt.inputs``: types, finiteness, ranges, input files, output paths) before the first
simulation and before the first write; outputs are written to a temporary file and moved into
place, so a failed write says so and leaves nothing half-written. Values from the user are printed
with their control characters escaped; JSON output never contains NaN or Infinity (null instead).
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import shlex
import signal
import sqlite3
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cmrt
from cmrt import inputs
from cmrt.errors import CmrtError, Terminated, TransientFault, clear_signals, note_signal, pending_termination
from cmrt.inputs import escape, shown
from cmrt.modes import BACKENDS, REFERENCE_MODES
from cmrt.optimize.settings import FAMILY_SIGMA0, STALE_AFTER_S, OptimizeSettings
from cmrt.service.query import search_summary
from cmrt.service.records import RUN_STATUSES, Run
from cmrt.service.store import DEFAULT_STORE, Store, disk_full, is_disk_full, open_store, resolve_path

# Start-up: a verb imports what it uses (MuJoCo, numba, scipy, pycma, dask: ~4 s in all) when it runs, so
# that `cmrt --help`, `cmrt runs` or `cmrt show` answer at once. Building the parser imports none of them:
# the defaults it shows come from ``cmrt.optimize.settings`` (constants only).
if TYPE_CHECKING:

    from cmrt.motion.curve import Cmrt
    from cmrt.motion.task import Task

EXIT_BAD_INPUT = 2
EXIT_TEMPFAIL = 75  # sysexits EX_TEMPFAIL: a fault of the machine; the run is back in the queue


class _Help(argparse.HelpFormatter):
    """Every option's help ends with its default, read from the parser (so the defaults are written once, where
    the option is declared or in ``OptimizeSettings``)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (default is None or default is False or default is argparse.SUPPRESS or "%(default)" in text
                or not action.option_strings and action.nargs is None):
            return text
        return f"{text} (default: %(default)s)" if text else "default: %(default)s"


class _Parser(argparse.ArgumentParser):
    """argparse, but usage errors are one line and exit 2 like every other bad input, and ``--help`` shows
    every default."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", _Help)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> None:  # type: ignore[override]
        raise CmrtError(message)


# --- output ------------------------------------------------------------------------
@dataclass(frozen=True)
class Output:
    """What a verb returns: ``data`` (printed as JSON with ``--json``) and its human form (a string, or a
    function of ``data`` returning one)."""

    data: object
    text: str | Callable[[object], str]
    status: int = 0  # the exit status (``cmrt check``: 1 when the reference is not feasible, like a linter)


def format_output(out: Output, as_json: bool) -> str:
    """The one formatter: JSON (one line for objects, indented for lists) or the text form."""
    if as_json:  # never NaN or Infinity: null
        return inputs.dumps(out.data, indent=None if isinstance(out.data, dict) else 2)
    return out.text(out.data) if callable(out.text) else out.text


def _table(rows: list[dict], keys: tuple[str, ...]) -> str:
    def fmt(v):
        if isinstance(v, float):
            return f"{v:.4g}"
        return "-" if v is None else escape(str(v))  # a task name from a user's file: no control characters

    cells = [list(keys)] + [[fmt(r.get(k)) for k in keys] for r in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(keys))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)) for row in cells)


# What each verdict rule says when it fails (``Evaluation.failed_rules``; docs/physics.md, *Success*), with the
# figure against its bound (``verdict_bounds`` of the report).
_RULE_TEXT = {
    "on_time": ("late", "timing_lag_s", ".3f", 1, "s"),
    "settled": ("not standing still after the clip: CoM", "final_com_speed_m_s", ".3f", 1, "m/s"),
    "plan": ("plan not carried out: planned vs executed CoP", "max_plan_cop_error_m", ".1f", 1000, "mm"),
    "ground_force": ("ground force", "peak_normal_force_bw", ".2f", 1, "x body weight"),
    "airborne": ("airborne", "airborne_s", ".3f", 1, "s"),
    "cop_margin": ("CoP outside the feet: margin", "min_cop_margin_m", ".1f", 100, "cm"),
    "final_pose": ("not back in its pose: final pose error", "final_pose_error_rad", ".3f", 1, "rad"),
}


def _broken(rule: str, r: dict) -> str:
    if rule == "performed":
        if r.get("task_success") is False:
            return "goal missed"
        if r.get("tracking_bound_rad") is None:
            return "footsteps not landed where asked" if r.get("footsteps_landed") is not None else "not performed"
        return (f"motion not performed (tracking {_n(r.get('tracking_error_rad'), '.3f')} rad, bound "
                f"{_n(r.get('tracking_bound_rad'), '.3f')}; final pose error "
                f"{_n(r.get('final_pose_error_rad'), '.3f')} rad)")
    if rule not in _RULE_TEXT:
        return rule
    words, key, spec, scale, unit = _RULE_TEXT[rule]
    bound = r.get("timing_lag_bound_s") if rule == "on_time" else (r.get("verdict_bounds") or {}).get(key)
    return f"{words} {_n(r.get(key), spec, scale)} {unit} (bound {_n(bound, spec, scale)})"


def _outcome(r: dict) -> str:
    """The verdict line: SUCCESS, or what broke the one rule (every failed rule, in order)."""
    if r["fell"]:
        return f"LOST BALANCE at {_n(r['fall_time_s'], '.3f')} s ({r['fall_reason']})"
    if r["success"]:
        return "SUCCESS (balance kept, motion performed on time, plan carried out, standing still)"
    rules = r.get("failed_rules") or []
    return "balance kept, but " + "; ".join(_broken(rule, r) for rule in rules) if rules else "not a success"


def _readable(key: str, value: object) -> str:
    """A stored value as a person reads it (``--json`` keeps full precision): times (``*_at``, unix seconds)
    as local ISO 8601, numbers to 6 significant digits, inside lists and tables too."""
    if key.endswith("_at") and isinstance(value, int | float) and not isinstance(value, bool):
        return datetime.datetime.fromtimestamp(value).astimezone().isoformat(timespec="seconds")

    def rounded(v):
        if isinstance(v, float):
            return float(f"{v:.6g}") if math.isfinite(v) else v
        if isinstance(v, list | tuple):
            return [rounded(x) for x in v]
        if isinstance(v, dict):
            return {k: rounded(x) for k, x in v.items()}
        return v

    if isinstance(value, dict | list):
        return inputs.dumps(rounded(value))
    return str(rounded(value))


def _n(x, spec: str, scale: float = 1.0) -> str:
    """A number for the text form; ``-`` for one that is not there (a NaN, null in JSON)."""
    if x is None:
        return "-"
    text = format(scale * x, spec)
    return format(0.0, spec) if float(text) == 0 else text  # -0.004 cm is "0.0", not "-0.0"


def _spatial_text(r: dict) -> str:
    """A 3D clip's report (``cmrt.sim.report.spatial_report``) as a few lines."""
    outcome = "SUCCESS" if r["success"] else "not a success: " + ", ".join(r["failed_rules"])
    speed = f" --speed {r['speed']:g}" if r["speed"] is not None else ""
    fall = ""
    if r["fell"]:
        d = r["fall_direction_xy"]
        fall = f"  fell at {r['fall_time_s']:.2f} s, the capture point out toward ({d[0]:+.2f}, {d[1]:+.2f})"
    return "\n".join([
        f"{escape(r['task'])}{speed}  body={r['body']}  curve={escape(r['curve'])}  reference={r['reference']}: "
        f"{outcome}" + fall,
        f"  planned vs executed CoP {_n(r['max_plan_cop_error_m'], '.2f', 1000)} mm  min CoP margin "
        f"{_n(r['min_cop_margin_m'], '.1f', 100)} cm  peak ground force {_n(r['peak_normal_force_bw'], '.2f')} x "
        f"body weight  [{r['wall_s']:.2f} s]",
        f"  max joint speed {_n(r['max_joint_speed_rad_s'], '.1f')} rad/s  planted feet slid "
        f"{_n(r['max_foot_slip_m'], '.2f', 100)} cm  final CoM speed {_n(r['final_com_speed_m_s'], '.3f')} m/s",
        *([_lift_text(r)] if "lift_off_s" in r else []),
        *([_pose_text(r)] if "tracking_bound_rad" in r else []),
        f"  judged as: {r['success_rule']}",
    ])


def _pose_text(r: dict) -> str:
    """A 3D pose change's own line: tracking, end pose and timing, as the planar report's."""
    return (f"  tracking {_n(r['tracking_error_rad'], '.3f')} rad (bound {_n(r['tracking_bound_rad'], '.3f')}); end "
            f"pose off by {_n(r['final_pose_error_rad'], '.3f')} rad; late {_n(r['timing_lag_s'], '.3f')} s (bound "
            f"{r['timing_lag_bound_s']:.3f})")


def _lift_text(r: dict) -> str:
    """A leg lift's own line: the anticipation and the timing."""
    return (f"  lift-off at {r['lift_off_s']:.2f} s, the CoM moved "
            f"{_n(r['com_shift_toward_stance_before_lift_off_m'], '.1f', 100)} cm toward the stance foot by then; the "
            f"foot ended {_n(r['foot_lift_m'], '.1f', 100)} cm up; late {_n(r['timing_lag_s'], '.3f')} s (bound "
            f"{r['timing_lag_bound_s']:.3f})")


def _report_text(r: dict) -> str:
    speed = f" --speed {r['speed']:g}" if r["speed"] is not None else ""
    track = _n(r["tracking_error_rad"], ".3f")
    if r["tracking_bound_rad"] is not None:
        track += f" (bound {r['tracking_bound_rad']:.3f})"
    return "\n".join([
        f"{escape(r['task'])}{speed}  curve={escape(r['curve'])}  reference={r['reference']}: {_outcome(r)}",
        f"  objective {_n(r['objective'], '.4f')}  (CoP-error 2-norm {_n(r['cop_error_norm'], '.4f')} m "
        f"+ penalty {_n(r['penalty'], '.2f')}; against its own reference CoP "
        f"{_n(r['cop_error_own_reference_norm'], '.4f')} m)",
        f"  min CoP margin {_n(r['min_cop_margin_m'], '.1f', 100)} cm  tracking error {track} rad  final pose error "
        f"{_n(r['final_pose_error_rad'], '.3f')} rad  [{r['wall_s']:.2f} s]",
        f"  peak ground force {_n(r['peak_normal_force_bw'], '.2f')} x body weight  airborne "
        f"{_n(r['airborne_s'], '.3f')} s  max joint speed {_n(r['max_joint_speed_rad_s'], '.1f')} rad/s",
        *([f"  steps {r['steps']} (lift-off at {', '.join(f'{t:.3f}' for t in r['step_times_s'])} s"
           + (f"; the first {r['step_liftoff_after_push_s']:.3f} s after the push"
              if r.get("step_liftoff_after_push_s") is not None else "")
           + (f"; hardest landing {r['max_touchdown_force_bw']:.2f} x body weight"
              if r.get("max_touchdown_force_bw") is not None else "")
           + (f"; planted feet slid {r['max_foot_slip_m'] * 100:.2f} cm"
              if r.get("max_foot_slip_m") is not None else "")
           + (f"; a stance foot's CoP rolled {r['min_stance_cop_roll'] * 100:.0f} % heel to toe at least"
              if r.get("min_stance_cop_roll") is not None else "")
           + (f"; walked at {r['walk_speed_m_s']:.2f} m/s" if r.get("walk_speed_m_s") is not None else "")
           + (f"; thorax within {r['max_thorax_pitch_deg']:.1f} deg of upright"
              if r.get("max_thorax_pitch_deg") is not None else "") + ")"]
          if r.get("steps") and isinstance(r.get("step_times_s"), list | tuple) else []),
        f"  planned vs executed CoP {_n(r.get('max_plan_cop_error_m'), '.2f', 1000)} mm (bound "
        f"{_n((r.get('verdict_bounds') or {}).get('max_plan_cop_error_m'), '.0f', 1000)})  timing lag "
        f"{_n(r.get('timing_lag_s'), '.3f')} s"
        + (f" (bound {_n(r['timing_lag_bound_s'], '.3f')} s)" if r.get("timing_lag_bound_s") is not None else ""),
        *([f"  judged as: {r['success_rule']}"] if r.get("success_rule") else []),
        *([_after_fall_text(r)] if r.get("fall_direction") is not None else []),
    ])


def _after_fall_text(r: dict) -> str:
    """The fall's direction and, for a topple played out, how violent it was."""
    line = f"  fell {r['fall_direction']} (by its {r['fall_direction_source'].replace('_', ' ')})"
    if r.get("after_fall_max_joint_speed_rad_s") is None:
        return line
    floor = r.get("after_fall_floor_contact_s")
    until = "the end" if floor is None else f"the body on the floor at {floor:.3f} s"
    return (f"{line}; to {until}: joint speed {_n(r['after_fall_max_joint_speed_rad_s'], '.1f')} rad/s, foot "
            f"force {_n(r['after_fall_peak_foot_force_bw'], '.2f')} x BW, foot lift "
            f"{_n(r['after_fall_max_foot_lift_m'], '.1f', 100)} cm; nothing on the floor (a hop) "
            f"{_n(r.get('after_fall_airborne_s'), '.3f')} s")


def _result(run: Run) -> dict:
    """A finished (or running) run as ``optimize``, ``best`` and ``demo`` report it."""
    return {
        "run_id": run.id,
        "task": run.task,
        "speed": run.speed,
        "reference": run.reference,
        "status": run.status,
        "best_objective": run.best_objective,
        "success": run.best_success,
        "fell": run.best_fell,
        "baseline_objective": run.baseline_objective,
        "baseline_success": run.baseline_success,
        "baseline_fell": run.baseline_fell,
        "evaluations": run.evaluations,
        "generations": run.generations,
        "stop_reason": run.stop_reason,
        "restarts": run.restarts or 0,
        "init": run.init_source or "none",
        "search": search_summary(run),
        "robust": run.robust is not None,
        "robustness": run.robustness,
        "wall_s": run.wall_s,
        "best_cmrt": run.best_cmrt,
        # how much lower the best objective is than with no CMRT (0: the zero CMRT itself is the best known)
        "improvement_over_zero": (None if run.baseline_objective is None or run.best_objective is None
                                  else run.baseline_objective - run.best_objective),
    }


def _outcome_word(success, fell) -> str:
    """A stored result's verdict, as ``optimize``, ``best`` and a worker print it."""
    return "SUCCESS" if success else ("balance LOST" if fell else "not a success (balance kept)")


def _run_line(run: Run) -> str:
    """One line for a finished run (what a worker prints as each run ends): its verdict, then where its search
    started and why it stopped."""
    speed = f" --speed {run.speed:g}" if run.speed is not None else ""
    verdict = _outcome_word(run.best_success, run.best_fell)
    best = "-" if run.best_objective is None else f"{run.best_objective:.4f}"
    return (f"run {run.id} {escape(run.task)}{speed}: {run.status}, best objective {best} {verdict}; "
            f"{escape(search_summary(run))}")


def _result_text(r: dict) -> str:
    speed = f" --speed {r['speed']:g}" if r["speed"] is not None else ""
    kind = "robust CMRT:   " if r["robust"] else "optimized CMRT:"
    lines = [
        f"run {r['run_id']} {escape(r['task'])}{speed}: {r['status']} in {_n(r['wall_s'], '.1f')} s, "
        f"{r['restarts']} restarts; {escape(r['search'])}",
        f"  zero CMRT:      objective {_n(r['baseline_objective'], '.4f')}  "
        f"{_outcome_word(r['baseline_success'], r['baseline_fell'])}",
        f"  {kind} objective {_n(r['best_objective'], '.4f')}  {_outcome_word(r['success'], r['fell'])}"
        + ("" if r.get("improvement_over_zero") is None else
           f"  ({r['improvement_over_zero']:.4f} better than no CMRT)" if r["improvement_over_zero"] > 0 else
           "  (no better than no CMRT: the zero CMRT is the best known)"),
    ]
    rb = r.get("robustness")
    if rb:
        survived = rb.get("survived_min_cop_margin_m")
        margin = "n/a" if survived is None else f"{survived * 100:.1f} cm"
        if rb["validation_total"] == 1:  # the 3D body: no ensemble yet
            outcome = "succeeds" if rb["validation_survived"] else "falls" if rb["validation_fell"] else "fails"
            lines.append(f"  validation:     the nominal clip alone {outcome} (no ensemble for this body); min CoP "
                         f"margin {margin}")
        else:
            lines.append(f"  validation:     {rb['validation_survived']}/{rb['validation_total']} perturbed clips "
                         f"succeed, {rb['validation_fell']} fall; min CoP margin of the successes {margin}")
    return "\n".join(lines)


class _Quiet:
    """No progress (``--no-progress``)."""

    def __call__(self, state, records, wall_s) -> None:
        pass

    def close(self) -> None:
        pass


def _progress(total_evals: int, label: str, enabled: bool, stream=None):
    """A run's progress on stderr (``stream``): a bar on a terminal, a line every few generations otherwise
    (``cmrt.service.progress``)."""
    from cmrt.service.progress import GenerationProgress

    if not enabled:
        return _Quiet()
    stream = sys.stderr if stream is None else stream
    return GenerationProgress(total_evals, label, bar=stream.isatty(), stream=stream)


# --- inputs ------------------------------------------------------------------------
def resolve_task(name: str, speed: float | None, sets: list[str] | None, reference: str | None = None,
                 steps: str | None = None) -> Task:
    """The task arguments (name or path, ``--speed``, ``--set``, ``--reference``, ``--steps``) -> a validated
    Task, of either body (a sequence's motions are planar: ``cmrt.motion.sequence``)."""
    from cmrt.motion.taskfile import resolve_task as task_variant

    return task_variant(name, speed, inputs.parse_sets(sets), reference, steps)


def _warn_if_not_feasible(name: str, task: Task) -> None:
    """A user's task file (given by path) whose reference motion ``cmrt check`` finds not feasible gets one warning
    line on stderr naming the first violation; the run goes on. Shipped tasks are not checked here (it costs about
    a second; ``cmrt check`` checks them), nor tasks the check does not apply to (walks, steps)."""
    if Path(name).suffix != ".toml":
        return
    from cmrt.motion.feasibility import check_reference, not_checkable

    if not_checkable(task) is not None:
        return
    try:
        found = check_reference(task)
    except CmrtError as exc:  # advice only: the run goes on
        print(f"cmrt: warning: {escape(name)}: its reference motion was not checked: {inputs.one_line(str(exc))}",
              file=sys.stderr, flush=True)
        return
    if not found.feasible:
        print(f"cmrt: warning: {escape(name)}: its reference motion cannot be done on time with both feet flat: "
              f"{found.first_violation} (cmrt check {shlex.quote(escape(name))})", file=sys.stderr, flush=True)


def _curve(args, spec: str, task: Task, flag: str = "--curve") -> tuple[Cmrt, str]:
    """A ``--curve``/``--compare`` value -> (curve, name); ``--force`` lets a CMRT made for another task in."""
    from cmrt.service.known import resolve_curve

    return resolve_curve(spec, task, args.store, flag, other_task=args.force)


def _store(path: str | None, readonly: bool = False, create: bool = True) -> Store:
    """The store at ``path`` (``--store``); a verb that only reads opens it read-only (``open_store`` checks
    the path is a regular file first). A verb that writes says when it creates a new store (a mistyped
    ``--store`` is then seen at once); one that needs runs in it (``create=False``: worker, requeue) refuses a
    missing store."""
    p = resolve_path(path)
    new = not readonly and not os.path.lexists(p)
    if new and not create:
        raise CmrtError(f"no CMRT store at {shown(str(p))} (queue jobs into it first: cmrt submit TASK --store "
                        f"{shown(str(p))})")
    store = open_store(path, readonly=readonly, create=create)
    if new:
        print(f"cmrt: created a new store at {escape(str(p))}", file=sys.stderr, flush=True)  # whole: to copy
    return store


def _store_arg(text: str) -> str:
    """``--store``: any path but an empty one (which named the default store, silently)."""
    try:
        resolve_path(text)
    except CmrtError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def _init_arg(value: str) -> str | int:
    if value in ("auto", "none"):
        return value
    if inputs.is_run_id(value):
        return inputs.run_id_arg(value)
    raise argparse.ArgumentTypeError(f"must be auto, none or a run id, got {shown(value)}")


def _force_arg(p: argparse.ArgumentParser, curves: bool = False) -> None:
    p.add_argument("--force", action="store_true",
                   help="replace an existing output file (never a store, a TOML file or a file this command reads)"
                   + ("; use a CMRT made for another task" if curves else ""))


def _check_out(args, value: str, flag: str, suffixes: tuple[str, ...] = ()) -> None:
    """An output path checked before any work: an existing file only with ``--force``, and never one the
    command reads (its store, task, sequence or curve file) or a store or TOML file."""
    reading = [resolve_path(getattr(args, "store", None))]
    reading += [v for k in ("task", "curve", "compare", "sequence", "family", "file")
                if isinstance(v := getattr(args, k, None), str) and os.path.isfile(v)]
    inputs.check_output(value, flag, suffixes, replace=args.force, reading=reading)


# --- shared argument groups ------------------------------------------------------------
def _task_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("task", help="a shipped task's name (cmrt tasks) or the path of a .toml task file")
    p.add_argument("--speed", type=inputs.arg(inputs.SPEED), help="the task's speed parameter (bend: duration T in s)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a task parameter")
    _reference_arg(p)
    p.add_argument("--steps", metavar="F:X:T[:S],...",
                   help="footsteps to take: foot R or L, where its centre lands (m from the start stance's centre, "
                   "+ forward), the step's duration (s) and optionally its lift-off time (s), comma-separated; "
                   "e.g. R:+0.30:0.6,L:+0.60:0.6 (docs/stepping.md)")


def _reference_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--reference", choices=REFERENCE_MODES, default=None,
                   help="where the controller's reference CoM/CoP come from: center (the support centre, as in "
                   "Anticipatory Balance Control, Rabbani et al. 2014: ABC) or "
                   "yu (GRF-weighted feet and Winter's CoP, reactive); default: the task file's, else center")


_SETTINGS = OptimizeSettings()  # the optimizer's defaults (written once, there), shown by --help


def _opt_args(p: argparse.ArgumentParser) -> None:
    """The optimizer's options, with OptimizeSettings' defaults."""
    p.add_argument("--seed", type=inputs.arg(inputs.SEED), default=_SETTINGS.seed, help="CMA-ES's seed")
    p.add_argument("--max-evals", type=inputs.arg(inputs.MAX_EVALS), default=_SETTINGS.max_evals,
                   help="evaluation budget (restarts included)")
    p.add_argument("--min-evals", type=inputs.arg(inputs.MIN_EVALS), default=None,
                   help=f"no slow-convergence stop before this (default: {_SETTINGS.min_evals}, or --max-evals if "
                   "smaller; more than --max-evals is refused)")
    p.add_argument("--popsize", type=inputs.arg(inputs.POPSIZE), default=_SETTINGS.popsize,
                   help="CMA-ES population of the first search")
    p.add_argument("--stall-generations", type=inputs.arg(inputs.STALL_GENERATIONS),
                   default=_SETTINGS.stall_generations,
                   help="a search whose best and best generation median improved < 0.1%% over this many "
                   "generations has stalled: it restarts (BIPOP: a doubled population, or a small one around "
                   "the best success) while budget remains")
    p.add_argument("--sigma0", type=inputs.arg(inputs.SIGMA0), default=None,
                   help=f"CMA-ES's initial step size (parameter units: 0.5 is 2.5 cm of CoM shift; default: "
                   f"{_SETTINGS.sigma0} from the zero CMRT, {FAMILY_SIGMA0} from a known one)")
    p.add_argument("--robust", action="store_true",
                   help="score every candidate on the task's ensemble of perturbed clips ([robust] table)")
    p.add_argument("--init", type=_init_arg, default="auto", metavar="auto|none|RUN",
                   help="start point: the nearest stored/library CMRT of the task (auto), "
                   "the zero CMRT (none), or a stored run's best")


def _backend_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--backend", choices=(AUTO_BACKEND, *BACKENDS), default=AUTO_BACKEND,
                   help="where candidates are simulated: batch (one process, many clips at once on mujoco.batch), "
                   "serial, loky or dask processes (+batch: each scoring a chunk as a batch); auto (default): "
                   "batch for a planar task, loky+batch for a 3D one (no lockstep batch: a process per core)")
    p.add_argument("--workers", type=inputs.arg(inputs.WORKERS),
                   help="processes (loky, LocalCluster; default: one per CPU)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="dask scheduler (default: a LocalCluster)")


AUTO_BACKEND = "auto"


def _backend(args, task: Task | None) -> str:
    """``--backend`` for ``task`` (None: jobs of any task, as a worker takes them): "auto" is the batched evaluator,
    but on a 3D task with more than one CPU ``loky+batch`` - its clips run one after another in a process (no
    lockstep batch yet), so a process per core: 28 s against 50 s for ``cmrt optimize leg-lift --seed 1 --init none``
    on 2 cores, the same run (docs/performance.md, *The 3D body*)."""
    if args.backend != AUTO_BACKEND:
        return args.backend
    spread = task is not None and task.body != "planar" and (os.cpu_count() or 1) > 1
    return "loky+batch" if spread else "batch"


def _submit_kwargs(args) -> dict:
    """The optimizer's options as ``jobs.submit`` takes them, checked (before any store is opened)."""
    from cmrt.service.jobs import check_settings

    settings = dict(seed=args.seed, max_evals=args.max_evals, popsize=args.popsize, sigma0=args.sigma0,
                    min_evals=args.min_evals, stall_generations=args.stall_generations)
    check_settings(**settings)
    return dict(settings, init=args.init)


def _opt_task(args, speed: float | None) -> Task:
    """The task an optimization runs: with ``--robust``, scored on its ensemble. A run id as ``--init`` must
    exist before a store is created or written."""
    task = resolve_task(args.task, speed, args.set, args.reference, args.steps)
    if task.body != "planar" and not task.params["stance_side"] and task.end_pose_deg is None:
        raise CmrtError(f"task {shown(task.name)}: a standing 3D task has no CMRT to optimize (a leg lift or a pose "
                        "change has; docs/body3d.md)")
    if isinstance(args.init, int):
        with _store(args.store, readonly=True) as store:
            store.run(args.init)
    _warn_if_not_feasible(args.task, task)
    return task.with_robust() if args.robust else task


# --- the verbs -----------------------------------------------------------------------
class Command:
    """One verb: ``add_arguments`` declares its options, ``run`` acts and returns what to print."""

    name = ""
    help = ""
    json_flag = True  # the verb has --json

    def add_arguments(self, p: argparse.ArgumentParser) -> None:
        """Declare the verb's own arguments (``--store`` and ``--json`` are added for every verb)."""

    def run(self, args: argparse.Namespace) -> Output | None:
        raise NotImplementedError


class Tasks(Command):
    name, help = "tasks", "list the shipped tasks"

    def run(self, args):
        from cmrt.motion.taskfile import available_tasks, load_task

        rows = []
        for name in available_tasks():
            t = load_task(name)
            rows.append({"name": name, "summary": t.summary, "speed_param": t.speed_param, "speed": t.speed,
                         "params": t.params, "param_ranges": {k: list(v) for k, v in t.param_ranges.items()}})

        def text(rows):
            width = max((len(r["name"]) for r in rows), default=0)
            return "\n".join(
                f"{r['name']:<{width}}  {r['summary']}"
                + (f" (speed: {r['speed_param']} = {r['speed']:g})" if r["speed_param"] else "") for r in rows)

        return Output(rows, text)


class Simulate(Command):
    name, help = "simulate", "simulate one clip of a task with a CMRT"

    def add_arguments(self, p):
        _task_args(p)
        p.add_argument("--curve", default="zero", help="zero | library (the paper's plain CMRT) | library-robust "
                       "| RUN | FILE.json")
        p.add_argument("--trace", metavar="FILE.npz", help="save the trajectories")
        _force_arg(p, curves=True)

    def run(self, args):
        from cmrt.sim.report import simulate_report

        if args.trace is not None:
            _check_out(args, args.trace, "--trace", (".npz",))
        task = resolve_task(args.task, args.speed, args.set, args.reference, getattr(args, "steps", None))
        wrote = "" if args.trace is None else f"\nwrote {escape(args.trace)}"
        curve, name = _curve(args, args.curve, task)
        if task.body != "planar":  # the 3D body: no feasibility check yet
            return Output(simulate_report(task, curve, name, args.trace), lambda r: _spatial_text(r) + wrote)
        _warn_if_not_feasible(args.task, task)
        return Output(simulate_report(task, curve, name, args.trace), lambda r: _report_text(r) + wrote)


class Check(Command):
    name, help = "check", ("can a task's reference motion be done on time with both feet flat? (exit 0 yes, 1 no; "
                           "docs/feasibility.md)")

    def add_arguments(self, p):
        _task_args(p)

    def run(self, args):
        from cmrt.motion.feasibility import check_reference

        task = resolve_task(args.task, args.speed, args.set, args.reference, args.steps)
        out = {}
        if task.body != "planar":  # its planar twin: the same sagittal motion, the same centroidal dynamics
            out = {"body": task.body, "checked_as": "its planar twin (docs/body3d.md)"}
            task = task.sagittal_twin()
        found = check_reference(task)
        return Output(found.to_dict() | out, _check_text, status=0 if found.feasible else 1)


def _check_text(r: dict) -> str:
    """``cmrt check``'s text form: the verdict, a table of what the motion asks against the limits (the keyed
    ankle and the best ankle path), and the three searches."""
    speed = f" --speed {r['speed']:g}" if r["speed"] is not None else ""
    keyed, best = r["keyed"], r["best"]
    rows = [("min vertical force (BW)", keyed["min_vertical_force_bw"], best["min_vertical_force_bw"],
             f">= {r['min_vertical_force_needed_bw']:g}"),
            ("friction needed", keyed["friction_needed"], best["friction_needed"], f"<= {r['floor_friction']:g}"),
            ("CoP margin (m)", keyed["min_cop_margin_m"], best["min_cop_margin_m"], ">= 0")]
    for joint in dict.fromkeys(n.split("_")[0] for n in r["torque_limit_nm"]):
        sides = [n for n in r["torque_limit_nm"] if n.split("_")[0] == joint]
        peak = [max(d["peak_torque_nm"][n] for n in sides) for d in (keyed, best)]
        rows.append((f"{joint} torque (N m)", *peak, f"<= {max(r['torque_limit_nm'][n] for n in sides):g}"))
    lines = [f"{escape(r['task'])}{speed}: {_verdict(r)}",
             *([f"  (the {r['body']} body, checked as {r['checked_as']})"] if "checked_as" in r else []),
             *(f"  (not included: {escape(x)})" for x in r["ignored"]),
             f"  {'':26}{'keyed ankle':>12}{'best ankle path':>17}   limit"]
    lines += [f"  {name:26}{_n(a, '12.3g')}{_n(b, '17.3g')}   {limit}" for name, a, b, limit in rows]
    lines.append(f"  {'ankle path free from':26}{'worst violation':>17}{'CoM shift (cm)':>20}")
    for name, s in r["searches"].items():
        lo, hi = s["com_shift_range_m"]
        lines.append(f"  {name + ' (t >= ' + format(s['free_from_s'], '.2f') + ' s)':26}"
                     f"{s['worst_violation']:+17.3f}{100 * lo:+12.1f} .. {100 * hi:+.1f}  {s['worst']}")
    lines.append(f"  [{r['wall_s']:.2f} s]")
    return "\n".join(lines)


def _verdict(r: dict) -> str:
    if not r["feasible"]:
        return f"NOT FEASIBLE: {r['first_violation']}"
    if not r["needs_anticipation"]:
        return "FEASIBLE (an ankle path starting after a 0.1 s reaction suffices)"
    when = "one from the motion's onset suffices" if r["from_onset_suffices"] else "it must start before the onset"
    return f"FEASIBLE, NEEDS ANTICIPATION (not with an ankle path starting after a 0.1 s reaction; {when})"


class Submit(Command):
    name, help = "submit", "queue an optimization job"

    def add_arguments(self, p):
        _task_args(p)
        _opt_args(p)

    def run(self, args):
        task = _opt_task(args, args.speed)
        kwargs = _submit_kwargs(args)
        from cmrt.service import jobs

        with _store(args.store) as store:
            run_id = jobs.submit(store, task, **kwargs)
        speed = f" --speed {task.speed:g}" if task.speed is not None else ""
        return Output({"run_id": run_id, "task": task.name, "speed": task.speed, "status": "queued"},
                      f"queued run {run_id}: {escape(task.name)}{speed}")


class Optimize(Command):
    name, help = "optimize", "run one optimization job (or a speed family) in the foreground"

    def add_arguments(self, p):
        _task_args(p)
        _opt_args(p)
        p.add_argument("--speeds", metavar="S1,S2,...", help="a speed family, each warm-started from the previous")
        p.add_argument("--family-sigma0", type=inputs.arg(inputs.SIGMA0), default=FAMILY_SIGMA0,
                       help="step size of the warm-started members")
        _backend_args(p)
        p.add_argument("--no-progress", action="store_true",
                       help="no progress on stderr (default: a bar on a terminal, else a line every 10 generations)")

    def run(self, args):
        if args.speeds:
            return self._family(args)
        from cmrt.optimize.parallel import Evaluator
        from cmrt.service import jobs

        task = _opt_task(args, args.speed)
        kwargs = _submit_kwargs(args)
        evaluator = Evaluator(_backend(args, task), args.workers, args.scheduler)  # fails before the store is touched
        try:
            with _store(args.store) as store:
                progress = _progress(args.max_evals, task.name, enabled=not args.no_progress)
                try:
                    run = jobs.optimize_now(store, task, evaluator, progress, **kwargs)
                finally:
                    progress.close()
        finally:
            evaluator.close()
        return Output(_result(run), _result_text)

    @staticmethod
    def _family(args) -> Output:
        """--speeds a,b,c: ``jobs.optimize_family``; each member's result is printed as it finishes."""
        from cmrt.optimize.parallel import Evaluator
        from cmrt.service import jobs

        items = args.speeds.split(",")
        if len(items) > inputs.MAX_SPEEDS:
            raise CmrtError(f"--speeds takes at most {inputs.MAX_SPEEDS} speeds, got {len(items)}")
        speeds = [inputs.number(v.strip(), "--speeds") for v in items]
        if args.speed is not None or isinstance(args.init, int):
            raise CmrtError("--speeds replaces --speed and a run id as --init (each member starts from the previous)")
        if args.family_sigma0 <= 0:
            raise CmrtError("--family-sigma0 must be > 0")
        tasks = [_opt_task(args, v) for v in speeds]  # validate every speed first
        kwargs = _submit_kwargs(args)

        def on_run(run: Run) -> None:
            if not args.json:
                print(_result_text(_result(run)), flush=True)

        evaluator = Evaluator(_backend(args, tasks[0]), args.workers, args.scheduler)
        try:
            with _store(args.store) as store:
                progress = _progress(args.max_evals, tasks[0].name, enabled=not args.no_progress)
                try:
                    runs = jobs.optimize_family(store, tasks, evaluator, family_sigma0=args.family_sigma0,
                                                on_generation=progress, on_run=on_run, **kwargs)
                finally:
                    progress.close()
        finally:
            evaluator.close()
        return Output([_result(r) for r in runs], "") if args.json else None


class Worker(Command):
    name, help = "worker", "claim and run queued (and orphaned) jobs"

    def add_arguments(self, p):
        p.add_argument("--until-idle", action="store_true", help="exit when the queue is empty")
        p.add_argument("--once", action="store_true", help="run at most one job")
        p.add_argument("--stale-after", type=inputs.arg(inputs.STALE_AFTER_S), metavar="SECONDS",
                       default=STALE_AFTER_S,
                       help="resume a running job whose heartbeat is older than this")
        _backend_args(p)
        p.add_argument("--no-progress", action="store_true",
                       help="no progress on stderr (default: a bar on a terminal, else a line every 10 generations)")

    def run(self, args):
        from cmrt.optimize.parallel import Evaluator
        from cmrt.service import jobs

        shown_progress = [_Quiet()]  # the running run's bar or lines (on stderr: stdout stays the runs' lines)

        def on_claim(c):
            if not args.json:
                print(f"worker {jobs.worker_id()}: run {c.run_id} (attempt {c.attempt})", flush=True)
            shown_progress[0].close()
            shown_progress[0] = _progress(store.run(c.run_id).max_evals, f"run {c.run_id}",
                                          enabled=not args.no_progress)

        def on_generation(state, records, wall_s) -> None:
            shown_progress[0](state, records, wall_s)

        def on_failure(run_id: int, message: str) -> None:
            print(f"cmrt: worker: run {run_id}: {message}", file=sys.stderr, flush=True)

        def on_done(run: Run) -> None:
            shown_progress[0].close()
            shown_progress[0] = _Quiet()
            if not args.json:
                print(f"  {_run_line(run)}", flush=True)

        def on_idle() -> None:
            if not args.json:
                print(f"worker {jobs.worker_id()}: no queued job in {shown(str(resolve_path(args.store)))}; "
                      "waiting for one (cmrt submit ...; Ctrl-C stops)", flush=True)

        if not (math.isfinite(args.stale_after) and args.stale_after > 0):
            raise CmrtError(f"--stale-after must be a finite number of seconds > 0, got '{args.stale_after}'")
        evaluator = Evaluator(_backend(args, None), args.workers, args.scheduler)
        try:
            with _store(args.store, create=False) as store:
                done = jobs.work(store, evaluator, until_idle=args.until_idle, once=args.once,
                                 stale_after_s=args.stale_after, on_claim=on_claim, on_failure=on_failure,
                                 on_done=on_done, on_idle=on_idle, on_generation=on_generation)
        finally:
            shown_progress[0].close()
            evaluator.close()
        return Output({"finished": done}, f"worker finished runs: {', '.join(map(str, done)) or 'none'}")


class Requeue(Command):
    name, help = "requeue", "put a failed run back in the queue (it resumes from its last checkpoint)"

    def add_arguments(self, p):
        p.add_argument("run", type=int)

    def run(self, args):
        with _store(args.store, create=False) as store:
            run = store.requeue(args.run)
        return Output({"run_id": run.id, "status": run.status}, f"run {run.id} is queued again")


class Jobs(Command):
    name, help = "jobs", "list jobs and their status"
    KEYS = ("id", "task", "speed", "status", "worker", "attempt", "evaluations", "heartbeat_at", "error")

    def add_arguments(self, p):
        p.add_argument("--status", choices=RUN_STATUSES)

    def run(self, args):
        with _store(args.store, readonly=True) as store:
            rows = [{k: getattr(r, k) for k in self.KEYS} for r in store.runs(status=args.status)]
        shown_rows = [{**r, "heartbeat_at": None if r["heartbeat_at"] is None else
                       _readable("heartbeat_at", r["heartbeat_at"])} for r in rows]
        return Output(rows, lambda _: _table(shown_rows, self.KEYS[:-1]))


class Runs(Command):
    name, help = "runs", "list stored runs"
    COLUMNS = ("id", "task", "speed", "reference", "status", "seed", "best_objective", "best_success",
               "baseline_objective", "baseline_success", "evaluations", "stop_reason")

    def add_arguments(self, p):
        p.add_argument("--task")
        p.add_argument("--reference", choices=REFERENCE_MODES, help="only runs with this reference mode")

    def run(self, args):
        from cmrt.service import query

        with _store(args.store, readonly=True) as store:
            rows = [query.run_summary(r) for r in store.runs(task=args.task, reference=args.reference)]
        return Output(rows, _table(rows, self.COLUMNS))


class Show(Command):
    name, help = "show", "one run in detail"

    def add_arguments(self, p):
        p.add_argument("run", type=inputs.run_id_arg)

    def run(self, args):
        from cmrt.service import query

        with _store(args.store, readonly=True) as store:
            d = query.run_details(store, args.run)

        def text(d):
            return "\n".join(f"{k:20s} {escape(_readable(k, v))}" for k, v in d.items() if k != "task_definition")

        return Output(d, text)


class Best(Command):
    name, help = "best", "the best finished run for a task and speed"

    def add_arguments(self, p):
        _task_args(p)

    def run(self, args):
        from cmrt.service import query

        task = resolve_task(args.task, args.speed, args.set, args.reference, getattr(args, "steps", None))
        with _store(args.store, readonly=True) as store:
            return Output(_result(query.best_run(store, task)), _result_text)


class Export(Command):
    name, help, json_flag = "export", "export a run's evaluations", False

    def add_arguments(self, p):
        p.add_argument("run", type=inputs.run_id_arg)
        p.add_argument("--format", choices=("json", "csv"), default="json",
                       help="json: the run, its generations and evaluations; csv: one row per evaluation")
        p.add_argument("--out", metavar="FILE.json|FILE.csv", help="write to this file (its suffix the format's)")
        _force_arg(p)

    def run(self, args):
        from cmrt.service import query

        if args.out is not None:
            _check_out(args, args.out, "--out", (f".{args.format}",))
        with _store(args.store, readonly=True) as store:
            text = query.export_run(store, args.run, args.format)
        if args.out is not None:
            inputs.write_text(args.out, text, "--out")
            return Output(None, f"wrote {escape(args.out)} ({args.format}, run {args.run})")
        return Output(None, text.rstrip("\n"))


class Interpolate(Command):
    name, help = "interpolate", "a CMRT for a new speed (or other parameter) from stored or library results"

    def add_arguments(self, p):
        _task_args(p)
        p.add_argument("--param", help="the parameter to interpolate over (default: the task's speed)")
        p.add_argument("--from", dest="source", choices=("library", "store"), default="library",
                       help="where the CMRTs at neighbouring values come from")
        p.add_argument("--out", metavar="FILE.json", help="write the CMRT (usable as --curve FILE.json)")
        _force_arg(p)

    def run(self, args):
        from cmrt.service.interpolate import interpolate, to_json

        if args.param is not None:
            inputs.param_name(args.param, "--param")
        if args.out is not None:
            _check_out(args, args.out, "--out", (".json",))
        task = resolve_task(args.task, args.speed, args.set, args.reference, getattr(args, "steps", None))
        store = _store(args.store, readonly=True) if args.source == "store" else None
        try:
            r = interpolate(task, args.param, args.source, store)
        finally:
            if store:
                store.close()
        text = to_json(r)
        if args.out is not None:
            inputs.write_text(args.out, text + "\n", "--out")
        if r.extrapolated:
            print(f"cmrt: warning: {r.param} = {r.value:g} is outside the optimized range "
                  f"[{r.sources[0][0]:g}, {r.sources[1][0]:g}]: extrapolated", file=sys.stderr)
        src = " and ".join(f"{lab}" for _, lab in r.sources)
        human = (
            f"{escape(task.name)} {r.param} = {r.value:g}: {'extrapolated' if r.extrapolated else 'interpolated'} "
            f"from {src} (weight {r.weight:.3f})\n"
            f"  knots {', '.join(f'{t:.3f}' for t in r.curve.knot_times_s)} s; values "
            f"{', '.join(f'{100 * v:+.2f}' for v in r.curve.values_m)} cm"
            + (f"; across {', '.join(f'{100 * v:+.2f}' for v in r.curve.cross_values_m)} cm"
               if r.curve.cross_values_m is not None else "")
            + (f"\nwrote {escape(args.out)}" if args.out is not None else "")
        )
        return Output(json.loads(text), human)


class Sequence(Command):
    name, help = "sequence", "simulate a sequence of pose changes with superposed (or zero) CMRTs"

    def add_arguments(self, p):
        p.add_argument("file", help="a shipped sequence's name (four-poses, four-poses-3d) or the path of a .toml "
                                    "sequence file")
        p.add_argument("--curve", choices=("superposed", "zero"), default="superposed",
                       help="superposed: each motion's CMRT shifted to its start and summed (Anticipatory Balance "
                       "Control, section 4.2)")
        p.add_argument("--trace", metavar="FILE.npz")
        _force_arg(p)

    def run(self, args):
        from cmrt.motion.curve import Cmrt
        from cmrt.motion.sequence import load_sequence
        from cmrt.service.interpolate import superpose
        from cmrt.sim.report import sequence_report

        if args.trace is not None:
            _check_out(args, args.trace, "--trace", (".npz",))
        seq = load_sequence(args.file)
        curve = superpose(seq) if args.curve == "superposed" else Cmrt.zero(seq.clip_s)
        r = sequence_report(seq, curve, args.curve, args.trace)
        return Output(r, lambda r: f"{escape(seq.name)} ({len(seq.motions)} motions, {seq.clip_s:.2f} s) "
                      f"curve={args.curve}: {_outcome(r)}\n  objective {_n(r['objective'], '.4f')}  max |CoP error| "
                      f"{_n(r['max_cop_error_m'], '.4f')} m  final pose error {_n(r['final_pose_error_rad'], '.4f')} "
                      f"rad  timing lag {_n(r['timing_lag_s'], '.3f')} s"
                      + ("" if r["fall_direction"] is None else "\n" + _after_fall_text(r))
                      + ("" if args.trace is None else f"\nwrote {escape(args.trace)}"))


FILE_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg", ".mp4", ".json", ".csv", ".npz", ".sqlite", ".toml")


class Plot(Command):
    name, help = "plot", "figures of a stored run (CoP error, CMRT, convergence)"

    def add_arguments(self, p):
        p.add_argument("run", type=inputs.run_id_arg, nargs="?",
                       help="a stored run: its CoP error, CMRT and convergence figures")
        p.add_argument("--family", metavar="TASK", help="the task's speed family from the library (Anticipatory "
                       "Balance Control, Fig. 5)")
        p.add_argument("--sequence", metavar="FILE", help="a sequence's superposed CMRTs (Anticipatory Balance "
                       "Control, Fig. 6)")
        p.add_argument("--out-dir", dest="out", default="plots", metavar="DIR",
                       help="the directory the figures are written to (--out names a file in every other verb)")
        p.add_argument("--out", dest="out_file", help=argparse.SUPPRESS)
        _force_arg(p)

    def run(self, args):
        from cmrt.viz import plot  # matplotlib: only this verb pays for it

        if args.out_file is not None:
            raise CmrtError("plot writes several figures into a directory: give --out-dir DIR (--out is a file "
                            "in the other verbs)")
        if args.run is None and not args.family and not args.sequence:
            raise CmrtError("plot what? give a RUN, --family TASK or --sequence FILE")
        if Path(args.out).suffix.lower() in FILE_SUFFIXES:  # plot x.png made a directory named x.png
            raise CmrtError(f"--out-dir is the directory the figures go into, not a file: {shown(args.out)} "
                            "(give a directory, e.g. --out-dir plots)")
        out = inputs.output_dir(args.out, "--out-dir")  # created and checked before anything is simulated
        family = out / f"{Path(args.family).stem}_family.png" if args.family else None
        sequence = out / f"{Path(args.sequence).stem}_sequence.png" if args.sequence else None
        targets = (plot.run_figure_paths(args.run, out) if args.run is not None else []) + [
            t for t in (family, sequence) if t is not None]
        for target in targets:  # every file it would write, before anything is simulated
            _check_out(args, str(target), "--out-dir")
        paths = []
        if args.run is not None:
            with _store(args.store, readonly=True) as store:
                paths += [str(p) for p in plot.plot_run(store, args.run, out)]
        if family:
            paths.append(str(plot.plot_family(args.family, family)))
        if sequence:
            paths.append(str(plot.plot_sequence(args.sequence, sequence)))
        return Output({"run_id": args.run, "files": paths}, "\n".join(f"wrote {escape(p)}" for p in paths))


class Render(Command):
    name, help = "render", "render a clip (PNG filmstrip or MP4), optionally beside another"

    def add_arguments(self, p):
        _task_args(p)
        p.add_argument("--curve", default="library", help="zero | library | RUN | FILE.json")
        p.add_argument("--compare", help="a second CMRT to show beside it (e.g. zero)")
        p.add_argument("--out", required=True, metavar="FILE.png|FILE.mp4",
                       help="the file to write: a PNG filmstrip or an MP4 video")
        p.add_argument("--frames", type=inputs.arg(inputs.FRAMES), default=8, help="filmstrip frames (PNG)")
        p.add_argument("--fps", type=inputs.arg(inputs.FPS), default=30, help="video frame rate (MP4)")
        _force_arg(p, curves=True)

    def run(self, args):
        from cmrt.viz.render import OUT_SUFFIXES, render  # OpenGL: only this verb pays for it

        _check_out(args, args.out, "--out", OUT_SUFFIXES)  # before anything is simulated
        task = resolve_task(args.task, args.speed, args.set, args.reference, getattr(args, "steps", None))
        curve, name = _curve(args, args.curve, task)
        compare, cname = _curve(args, args.compare, task, "--compare") if args.compare else (None, "")
        if task.body != "planar":
            from cmrt.viz.render3d import render_3d

            r = render_3d(task, curve, args.out, compare, (f"{name} CMRT", f"{cname} CMRT"), n_frames=args.frames,
                          fps=args.fps)
        else:
            r = render(task, curve, args.out, compare, (f"{name} CMRT", f"{cname} CMRT"), n_frames=args.frames,
                       fps=args.fps)
        lines = [f"wrote {escape(r['out'])} ({r['frames']} frames)"] + [
            f"  {escape(c['label'])}: {c['verdict']}, objective {c['objective']:.4f}"
            for c in r["clips"]
        ]
        return Output(r, "\n".join(lines))


class Bench(Command):
    name, help = "bench", "time the physics floor, batched, serial and every backend"

    def add_arguments(self, p):
        p.add_argument("--task", default="bend", help="the task whose clips are timed")
        p.add_argument("--speed", type=inputs.arg(inputs.SPEED),
                       help="the task's speed parameter (default: the task's own; the bend's is 0.4 s)")
        p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a task parameter")
        _reference_arg(p)
        p.add_argument("--population", type=inputs.arg(inputs.POPULATION), default=16,
                       help="clips per timed generation (CMA-ES candidates)")
        p.add_argument("--repeat", type=inputs.arg(inputs.REPEAT), default=5, help="timings per measurement")
        p.add_argument("--backends", help=f"comma-separated subset of {','.join(BACKENDS)}")
        p.add_argument("--workers", type=inputs.arg(inputs.WORKERS),
                       help="processes of the parallel backends (default: one per CPU)")
        p.add_argument("--no-optimize", action="store_true",
                       help="skip timing a full 'cmrt optimize TASK --seed 1 --init none' (throwaway store)")

    def run(self, args):
        from cmrt.optimize.bench import run_bench

        backends = tuple(args.backends.split(",")) if args.backends else BACKENDS
        unknown = [b for b in backends if b not in BACKENDS]
        if unknown:
            raise CmrtError(f"--backends must be a comma-separated subset of {', '.join(BACKENDS)}, got "
                            f"{shown(args.backends)}")
        task = resolve_task(args.task, args.speed, args.set, args.reference, getattr(args, "steps", None))
        return Output(run_bench(task, args.population, args.repeat, backends, args.workers,
                                None if args.no_optimize else _timed_optimization), self._text)

    @staticmethod
    def _text(r: dict) -> str:
        floor = r["physics_only_s_per_clip"]
        rows = [
            ("physics only (floor: replay)", floor),
            *([("zero-torque collapse (old floor)", r["zero_torque_s_per_clip"])]
              if r["zero_torque_s_per_clip"] is not None else []),
            ("batched evaluator", r["batched_s_per_clip"]),
            ("serial, one clip at a time", r["serial_s_per_clip"]),
            (f"robust, per member ({r['robust_members']}/cand.)", r["robust_s_per_member"]),
        ]
        rows += [(f"generation, backend {b}", v) for b, v in r["generation_s_per_clip"].items()]
        return "\n".join(
            [f"{r['task']} speed {r['speed']}, population {r['population']}, {r['steps_per_clip']} steps/clip, "
             f"control {r['control_hz']:.0f} Hz ({r['machine']}, median of {r['repeat']} alternating rounds)"]
            + [f"  {name:32s} {1e3 * v:8.2f} ms/clip   x{v / floor:5.2f}" for name, v in rows]
            + [f"  floor: {r['floor']}; {r['steps_replayed']} steps replayed, "
               f"{r['steps_evaluated']} evaluated; replayed CoM off the closed loop's by at most "
               f"{r['replay_max_divergence_m']:.2g} m",
               f"  batched / floor within each round: median {r['ratio_batched_to_physics']:.2f} "
               f"(min {r['ratio_batched_to_physics_min']:.2f}, max {r['ratio_batched_to_physics_max']:.2f})",
               f"  robust ensemble member / plain clip within each round: median "
               f"{r['ratio_robust_member_to_plain']:.2f}"]
            + ([f"  full optimization (seed 1, cold): {r['optimize_evaluations']} evaluations in "
                f"{r['optimize_wall_s']:.1f} s; evaluations x floor = {r['optimize_floor_s']:.1f} s "
                f"(x{r['ratio_optimize_to_floor']:.2f})"] if "optimize_wall_s" in r else []))


def _timed_optimization(task: Task) -> tuple[int, float]:
    """``cmrt optimize TASK --seed 1 --init none`` (otherwise default settings, batched backend) into a
    throwaway store: (evaluations, wall seconds). Cold, because a warm start from the shipped library
    curve ends the fast bend after one generation - that would time start-up, not the optimization -
    and the user's store is neither read nor written."""
    from cmrt.service import jobs

    with tempfile.TemporaryDirectory() as tmp, open_store(Path(tmp) / "bench.db") as store:
        t0 = time.perf_counter()
        run = jobs.optimize_now(store, task, seed=1, init="none")
        return run.evaluations, time.perf_counter() - t0


class Demo(Command):
    name, help, json_flag = "demo", "the main job: optimize the fast bend into the store, show the result", False

    def add_arguments(self, p):
        _backend_args(p)

    def run(self, args):
        """Optimize the fast bend into the store and show the stored result (printed as it goes: it takes a
        while)."""
        from cmrt.motion.curve import Cmrt
        from cmrt.motion.library import library_curve
        from cmrt.motion.taskfile import load_task
        from cmrt.optimize.parallel import Evaluator
        from cmrt.service import jobs, query
        from cmrt.sim.report import simulate_report

        task = load_task("bend").with_speed(0.4)
        print("Fast bend (T = 0.4 s: a rotation at the hips into a crouched bend, both feet planted). The reactive "
              "controller alone:")
        print(_report_text(simulate_report(task, Cmrt.zero(task.clip_s, task.cmrt_axes), "zero")))
        store_path = resolve_path(args.store)
        print(f"\nOptimizing its CMRT with CMA-ES (seed 1) into {store_path} ...", flush=True)
        evaluator = Evaluator(_backend(args, task), args.workers, args.scheduler)
        try:
            with _store(args.store) as store:
                progress = _progress(_SETTINGS.max_evals, task.name, enabled=sys.stderr.isatty())
                try:
                    run = jobs.optimize_now(store, task, evaluator, progress, seed=1, init="none")
                finally:
                    progress.close()
                stored = query.best_run(store, task)
                curve = query.run_curve(store, run.id)
        finally:
            evaluator.close()
        print(f"\nStored in {store_path}; the best run for this task ('cmrt best bend --speed 0.4'):")
        print(_result_text(_result(stored)))
        print(f"\nReplaying run {run.id}'s CMRT ('cmrt simulate bend --speed 0.4 --curve {run.id}'):")
        print(_report_text(simulate_report(task, curve, f"run {run.id}")))
        print("\nThe library CMRT shipped with cmrt (a longer run; 'cmrt simulate bend --speed 0.4 --curve "
              "library'):")
        print(_report_text(simulate_report(task, library_curve(task), "library")))
        return None


PORT = inputs.Range(0, 65535, integer=True)


class Dashboard(Command):
    name, help, json_flag = "dashboard", "serve a read-only web dashboard of the store (runs, CMRTs, clips)", False

    def add_arguments(self, p):
        p.add_argument("--host", default="127.0.0.1", help="address to listen on (any but the loopback shows the store "
                       "to the network: there is no login)")
        p.add_argument("--port", type=inputs.arg(PORT), default=8080, help="TCP port (0: any free one)")

    def run(self, args):
        """Check the store opens read-only and the address is free (one line, exit 2 otherwise), then serve until
        Ctrl-C."""
        from cmrt.dashboard.app import DashboardConfig, bind, serve, url_of  # Starlette, uvicorn: only this verb

        path = resolve_path(args.store)
        with _store(args.store, readonly=True) as store:  # a damaged or foreign store: refused before serving
            store.runs()
        config = DashboardConfig(store_path=path, host=args.host, port=args.port)
        sock = bind(config)
        print(f"cmrt dashboard: {url_of(sock)} shows {escape(str(path))} read-only (Ctrl-C stops)", flush=True)
        try:
            serve(config, sock)
        finally:
            sock.close()
        return None


COMMANDS: tuple[Command, ...] = (
    Tasks(), Simulate(), Check(), Submit(), Optimize(), Worker(), Requeue(), Jobs(), Runs(), Show(), Best(), Export(),
    Interpolate(), Sequence(), Plot(), Render(), Bench(), Demo(), Dashboard(),
)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser: one sub-command per :data:`COMMANDS` entry."""
    p = _Parser(prog="cmrt", description="Anticipatory balance: center-of-mass reference trajectories.")
    p.add_argument("--version", action="version", version=f"cmrt {cmrt.__version__}")
    sub = p.add_subparsers(dest="verb", required=True, parser_class=_Parser)
    common = _Parser(add_help=False)
    common.add_argument("--store", metavar="PATH", type=_store_arg,
                        help=f"SQLite store (default $CMRT_STORE or {DEFAULT_STORE})")
    for command in COMMANDS:
        sp = sub.add_parser(command.name, help=command.help, parents=[common])
        if command.json_flag:
            sp.add_argument("--json", action="store_true", help="machine-readable output")
        command.add_arguments(sp)
        sp.set_defaults(command=command)
    return p


HELP_WIDTH = 100  # columns of the help text in docs/reference/cli.md


def help_reference() -> str:
    """``docs/reference/cli.md``: ``cmrt --help`` and every verb's, as argparse prints them (``tools/cli_reference.py``
    writes it; a test keeps it in sync)."""
    previous = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(HELP_WIDTH)  # argparse wraps at the terminal's width
    try:
        parser = build_parser()
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parts = ["# The `cmrt` command\n",
                 "Generated from the argument parser by `python tools/cli_reference.py` (a test checks it is current). "
                 "Every verb takes `--store PATH`; a verb with `--json` prints machine-readable output. Bad input "
                 "prints one line, `cmrt: error: ...`, and exits with status 2.\n",
                 "```text\n" + parser.format_help().rstrip() + "\n```\n"]
        for name, verb in sub.choices.items():
            parts.append(f"## cmrt {name}\n\n```text\n{verb.format_help().rstrip()}\n```\n")
        return "\n".join(parts)
    finally:
        if previous is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = previous


def main(argv: list[str] | None = None) -> int:
    """Run one verb; exit status 0 (``check``: 1 for a reference that is not feasible), 2 for bad input (one line
    on stderr), 130 on Ctrl-C."""
    args = None
    clear_signals()
    # a worker gives its run back, as on Ctrl-C: a closed terminal (SIGHUP) and SIGQUIT too, not only SIGTERM
    previous = {sig: signal.signal(sig, _terminate) for sig in TERMINATING_SIGNALS}
    try:
        try:
            args = build_parser().parse_args(argv)
            if getattr(args, "workers", 0) is None:  # one per CPU: not a default --help (or the docs) could print
                args.workers = os.cpu_count() or 1
            _check_environment()
            out = args.command.run(args)
        except (CmrtError, sqlite3.DatabaseError) as exc:  # a signal inside an SQLite step ends as "interrupted"
            terminated = pending_termination()
            if terminated is not None:
                raise terminated from exc
            raise
        if out is not None:
            print(format_output(out, getattr(args, "json", False)))
        return 0 if out is None else out.status
    except CmrtError as exc:
        print(f"cmrt: error: {inputs.one_line(str(exc))}", file=sys.stderr)  # one line, control characters escaped
        return EXIT_BAD_INPUT
    except sqlite3.DatabaseError as exc:  # a damaged store (store.py refuses foreign files; damage shows in a query)
        path = resolve_path(getattr(args, "store", None))
        if is_disk_full(exc, path):  # a read that needed room beside the store (its -shm) and found none
            print(f"cmrt: error: {inputs.one_line(str(disk_full(path)))}", file=sys.stderr)
            return EXIT_TEMPFAIL
        print(f"cmrt: error: {inputs.one_line(f'store {shown(str(path))} is damaged: {exc}')}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except TransientFault as exc:
        print(f"cmrt: error: {inputs.one_line(str(exc))}", file=sys.stderr)
        return EXIT_TEMPFAIL
    except Terminated as exc:
        print(f"cmrt: terminated ({signal.Signals(exc.signum).name}){_resume_hint(exc, args)}", file=sys.stderr)
        return 128 + exc.signum
    except KeyboardInterrupt as exc:
        print(f"cmrt: interrupted{_resume_hint(exc, args)}", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into `head` and the like
        sys.stderr.close()
        return 0
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _resume_hint(exc: KeyboardInterrupt, args: argparse.Namespace | None) -> str:
    """What an interruption left: the run given back to the queue, and the command that resumes it."""
    run_id = getattr(exc, "released_run", None)
    if run_id is None:
        return ""
    store = shlex.quote(escape(str(resolve_path(getattr(args, "store", None)))))  # whole, ready to paste
    return (f": run {run_id} is back in the queue, its checkpoint kept; resume it with: "
            f"cmrt worker --once --store {store}")


TERMINATING_SIGNALS = (signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)
THREADS = inputs.Range(1, 256, integer=True)


def _check_environment() -> None:
    """The environment variables cmrt reads, checked before anything runs (one line, exit 2), not deep
    inside a worker's first generation."""
    from cmrt.optimize.memory import memory_share

    memory_share()
    text = os.environ.get("CMRT_THREADS", "").strip()
    if text:
        THREADS.check(text, "$CMRT_THREADS")


def _terminate(signum, frame) -> None:
    note_signal(signum)  # seen even where sqlite3 swallows the exception (a signal inside an SQLite step)
    raise Terminated(signum)

