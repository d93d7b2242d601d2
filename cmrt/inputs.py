"""Everything a user hands in, checked before the first simulation and before the first write.

Task files, ``--set``, every number on the command line, sequence files, CMRT JSON, run ids,
input files and output paths go through the small typed checks here. Each check returns
a clean value or raises :class:`~cmrt.errors.CmrtError` with one line that names the file or
flag and the offending value (:func:`shown`: at most ``MAX_SHOWN`` characters, control
characters escaped), which the CLI prints as ``cmrt: error: ...`` with exit status 2.

**Hand-written, no validation library.** pydantic or msgspec would be a new runtime
dependency for about a dozen shapes, and their error reports are multi-line lists keyed
by a location path, which the CLI would have to rewrite into one line anyway. What has to
be checked is mostly *ranges* (finite, inside physical bounds) and *resources* (file kind,
size, nesting depth, clip length), not the shape of deep documents, so plain functions over
:class:`Range` are shorter and say exactly what a user sees.

Rules (the ranges, docs/reference/commands.md quotes them):

* Every number that reaches MuJoCo or the store is finite and inside a documented
  :class:`Range`: text is parsed strictly (ASCII digits, optional sign, point and exponent;
  no ``nan``, ``inf``, ``1_0``, ``٣`` or ``²``), booleans are not numbers, and integers are
  refused past ``MAX_NUMBER_CHARS`` characters before Python converts them.
* **Clip length**: ``clip_s + tail_s <= MAX_RUN_S`` (60 s). A simulation allocates its
  per-step record up front for every simulation of a batch, recorded or not: about 0.6 kB
  per simulation and 2 ms physics step (measured with tracemalloc, 16 simulations: the
  humanoid alone 590 B, with the ball 630 B), so the longest clip - 60 s plus the 1 s a
  recorded fall plays out, 30 500 steps - takes ~19 MB per simulation, **~0.31 GB for a
  16-candidate batch with recording**, ~1.9 GB for the largest population (``POPSIZE``,
  100). Robust scoring multiplies by the ensemble's members (at most 1 + 2 x 4 push moments
  + 2 masses + 2 timings = 13). Without the bound ``--set clip_s=1e5`` asked for ~30 GB.
* Optimizer settings (:data:`SEED`, :data:`RUN_ID`, :data:`SIGMA0`, :data:`POPSIZE`,
  :data:`MAX_EVALS`, :data:`MIN_EVALS`, :data:`STALL_GENERATIONS`), worker and renderer
  settings: bounded integers or finite floats; seeds and run ids fit SQLite's signed 64 bits.
* Input files (:func:`read_text`): regular files only (a FIFO, ``/dev/stdin``, a device or
  a directory is refused without blocking: the file is opened non-blocking and checked with
  ``fstat``), at most ``MAX_FILE_BYTES``, UTF-8. TOML and JSON (:func:`parse_toml`,
  :func:`parse_json`) are refused beyond ``MAX_NESTING`` levels of brackets before parsing
  (and a RecursionError is reported as such if one still happens); JSON's ``NaN`` and
  ``Infinity`` are refused.
* Output files (:func:`check_output`, :func:`atomic_output`): checked before any work (the
  directory exists and a file can be created in it; an existing target is a regular file),
  written to a temporary file in the target's directory and moved over the target with
  ``os.replace``: a failed write leaves nothing, or the old file, behind, never half a file.

This module is in the base layer: it imports nothing of cmrt but ``errors``.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import json
import math
import os
import re
import stat
import tempfile
import tomllib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from cmrt.errors import CmrtError, DiskFull

MAX_SHOWN = 80  # characters of a user's value quoted in an error message
MAX_MESSAGE = 300  # characters of a whole error line
MAX_FILE_BYTES = 1_000_000  # task, sequence and CMRT files
MAX_NESTING = 32  # brackets / braces deep in a TOML or JSON input
MAX_NUMBER_CHARS = 40  # a number written with more characters than this is refused unparsed
MAX_RUN_S = 60.0  # clip_s + tail_s: the longest simulated clip (memory: see the module docstring)
INT64_MAX = 2**63 - 1


# --- showing user values --------------------------------------------------------------
def escape(text: str) -> str:
    """``text`` with every non-printable character (newline, escape, NUL, U+2028, a lone surrogate from a
    non-UTF-8 file name, ...) written as a Python escape, so printing it can neither break a line nor drive
    the terminal."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else c.encode("unicode_escape", "backslashreplace").decode("ascii")
                   for c in text)


def shown(value: object, limit: int = MAX_SHOWN) -> str:
    """A user's value for an error message: quoted, escaped, cut to ``limit`` characters (``...`` if cut)."""
    if isinstance(value, str):
        text = value
    elif isinstance(value, int) and not isinstance(value, bool) and abs(value) > 10**MAX_NUMBER_CHARS:
        text = f"<an integer of {int(value.bit_length() * math.log10(2)) + 1} digits>"
    else:
        try:
            text = repr(value)
        except (ValueError, RecursionError):
            text = f"<{type(value).__name__}>"
    out = escape(text[:limit])
    cut = len(text) > limit or len(out) > limit
    return f"'{out[:limit]}{'...' if cut else ''}'"


def one_line(message: str) -> str:
    """An error message as one printable line of at most ``MAX_MESSAGE`` characters."""
    out = escape(message.replace("\r\n", " ").replace("\n", " "))
    return out if len(out) <= MAX_MESSAGE else out[: MAX_MESSAGE - 3] + "..."


# --- numbers ---------------------------------------------------------------------------
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?", re.ASCII)
_INTEGER = re.compile(r"[+-]?[0-9]+", re.ASCII)
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*", re.ASCII)


@dataclass(frozen=True)
class Range:
    """An allowed interval of a number: [lo, hi], either end open; ``integer`` for counts and ids."""

    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False
    unit: str = ""

    def __str__(self) -> str:
        if not (math.isfinite(self.lo) or math.isfinite(self.hi)):
            return f"(-inf, inf){' ' + self.unit if self.unit else ''}"

        def fmt(x):
            return str(int(x)) if self.integer and math.isfinite(x) else f"{x:g}"

        body = f"{'(' if self.lo_open else '['}{fmt(self.lo)}, {fmt(self.hi)}{')' if self.hi_open else ']'}"
        return f"{body}{' ' + self.unit if self.unit else ''}"

    def contains(self, x: float) -> bool:
        """Whether ``x`` (finite) is inside."""
        above = x > self.lo if self.lo_open else x >= self.lo
        below = x < self.hi if self.hi_open else x <= self.hi
        return above and below

    def check(self, value: object, where: str, text: bool = True) -> float | int:
        """``value`` (an int or float, not a bool; or, with ``text``, a string parsed strictly: command-line
        values, not a file's) as a finite number inside the range; CmrtError naming ``where`` otherwise."""
        kind = "an integer" if self.integer else "a finite number"
        if isinstance(value, str) and not text:
            x = None
        else:
            x = _parse_integer(value) if self.integer else _parse_number(value)
        if x is None or not self.contains(x):
            bounds = f" in {self}" if math.isfinite(self.lo) or math.isfinite(self.hi) else ""
            raise CmrtError(f"{where} must be {kind}{bounds}, got {shown(value)}")
        return x


def _parse_number(value: object) -> float | None:
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        if abs(value) > 10**MAX_NUMBER_CHARS:
            return None
        return float(value)
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, str):
        text = value.strip(" ")
        if len(text) > MAX_NUMBER_CHARS or not _NUMBER.fullmatch(text):
            return None
        x = float(text)
        return x if math.isfinite(x) else None
    return None


def _parse_integer(value: object) -> int | None:
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return value if abs(value) <= 10**MAX_NUMBER_CHARS else None
    if isinstance(value, str):
        text = value.strip(" ")
        if len(text) > MAX_NUMBER_CHARS or not _INTEGER.fullmatch(text):
            return None
        return int(text)
    return None


def number(value: object, where: str, allowed: Range = Range(), text: bool = True) -> float:
    """A finite float inside ``allowed`` (default: any finite number); ``text=False`` for a value read from a
    file (TOML, JSON), where a number must be written as one, not as a string."""
    return float(allowed.check(value, where, text))


def is_run_id(text: str) -> bool:
    """Whether ``text`` is written as a run id: ASCII digits only (``str.isdigit`` also takes '²' and '٣')."""
    return isinstance(text, str) and 0 < len(text) <= MAX_NUMBER_CHARS and _INTEGER.fullmatch(text) is not None \
        and text[0] not in "+-"


def param_name(value: object, where: str) -> str:
    """A parameter name: ASCII letters, digits and underscores, not starting with a digit."""
    if not isinstance(value, str) or len(value) > 100 or not _NAME.fullmatch(value):
        raise CmrtError(f"{where} must be a parameter name (letters, digits, _), got {shown(value)}")
    return value


# The numbers a user gives on the command line (and the API checks again).
SEED = Range(0, INT64_MAX, integer=True)
RUN_ID = Range(1, INT64_MAX, integer=True)
SIGMA0 = Range(0.0, 10.0, lo_open=True)  # CMA-ES step in parameter units (1 = 5 cm of CoM shift)
POPSIZE = Range(2, 100, integer=True)  # x clip length: the batch's memory
MAX_EVALS = Range(1, 1_000_000, integer=True)
MIN_EVALS = Range(0, 1_000_000, integer=True)
STALL_GENERATIONS = Range(1, 100_000, integer=True)
STALE_AFTER_S = Range(0.0, 1e7, lo_open=True, unit="s")
WORKERS = Range(1, 256, integer=True)
SPEED = Range()  # any finite number; the task's own range decides
FRAMES = Range(1, 60, integer=True)  # filmstrip frames
FPS = Range(1, 60, integer=True)  # video frames per second
POPULATION = Range(1, 256, integer=True)  # bench
REPEAT = Range(1, 100, integer=True)  # bench
MAX_SPEEDS = 32  # members of a --speeds family
MAX_SETS = 64  # --set options

#: Ranges of the parameters every task has (``cmrt.motion.task.DEFAULT_PARAMS``); a prop declares its own
#: (``Prop.LIMITS``). Any other parameter of a task file is a finite number with |x| <= 1e9.
TASK_PARAMS: dict[str, Range] = {
    "clip_s": Range(0.0, MAX_RUN_S, lo_open=True, unit="s"),
    "preparation_s": Range(0.0, MAX_RUN_S, unit="s"),
    "duration_s": Range(0.0, MAX_RUN_S, unit="s"),
    "cop_sample_step_s": Range(0.001, 1.0, unit="s"),
    "stop_threshold": Range(0.0, 1e6),
    "push_force_n": Range(-1e4, 1e4, unit="N"),
    "push_force_y_n": Range(-1e4, 1e4, unit="N"),  # sideways, +y the body's left (a 3D task's: docs/body3d.md)
    # a 3D leg lift (docs/body3d.md): the foot stood on (+1 the left, -1 the right; 0 both, no lift) and the share
    # of T the lift takes (the rest is the weight shift)
    "stance_side": Range(-1.0, 1.0),  # -1, 0 or 1 (checked by the task)
    "lift_fraction": Range(0.1, 0.9),
    "push_start_s": Range(0.0, MAX_RUN_S, unit="s"),
    "push_duration_s": Range(0.0, MAX_RUN_S, unit="s"),
    "max_tracking_lag": Range(0.0, 1.0, lo_open=True),
    "tail_s": Range(0.5, MAX_RUN_S, unit="s"),
    "via_fraction": Range(0.0, 1.0, lo_open=True, hi_open=True),
    "stepping": Range(0.0, 2.0),  # 0, 1 or 2 (checked by the task)
    "push2_force_n": Range(-1e4, 1e4, unit="N"),
    "push2_start_s": Range(0.0, MAX_RUN_S, unit="s"),
    "push2_duration_s": Range(0.0, MAX_RUN_S, unit="s"),
    "push3_force_n": Range(-1e4, 1e4, unit="N"),
    "push3_start_s": Range(0.0, MAX_RUN_S, unit="s"),
    "push3_duration_s": Range(0.0, MAX_RUN_S, unit="s"),
    "step_time_s": Range(0.2, 1.0, unit="s"),
    "step_height_m": Range(0.01, 0.15, unit="m"),
    "planned_step_s": Range(0.0, 1.5, unit="s"),
    # a keyed gait (cmrt.motion.gait): a task has one when gait_steps > 0
    "gait_steps": Range(0.0, 20.0),  # whole (checked by the task)
    "gait_step_length_m": Range(0.05, 0.4, unit="m"),
    "gait_swing_s": Range(0.3, 1.5, unit="s"),
    "gait_double_support_s": Range(0.05, 1.0, unit="s"),
    "gait_first_step_s": Range(0.3, 5.0, unit="s"),
    "gait_lift_m": Range(0.0, 0.15, unit="m"),
    "gait_crouch_m": Range(0.0, 0.1, unit="m"),
    # the ground (cmrt.body.surface): Yu's slippery floor is 0.08, his slope 15 deg, his shaking plane +-20 deg
    "floor_friction": Range(0.01, 2.0),
    "slope_deg": Range(-25.0, 25.0, unit="deg"),
    "tilt_amplitude_deg": Range(0.0, 30.0, unit="deg"),
    "tilt_period_s": Range(0.5, 60.0, unit="s"),
    "sway_amplitude_m": Range(0.0, 0.3, unit="m"),
    "sway_period_s": Range(0.5, 60.0, unit="s"),
    "heave_amplitude_m": Range(0.0, 0.1, unit="m"),
    "heave_period_s": Range(0.5, 60.0, unit="s"),
    # Yu's floating box (cmrt.body.floating_box): 0 kg is no box
    "box_mass_kg": Range(0.0, 5000.0, unit="kg"),
    "box_stiffness_n_m": Range(500.0, 1e6, unit="N/m"),
    "box_damping_ratio": Range(0.0, 2.0),
}
OTHER_PARAM = Range(-1e9, 1e9)
POSE_DEG = Range(-360.0, 360.0, unit="deg")
FRACTION = Range(0.0, 1.0)


def param_range(key: str, extra: dict[str, Range] | None = None) -> Range:
    """The documented range of task parameter ``key`` (``extra``: a prop's)."""
    if extra and key in extra:
        return extra[key]
    return TASK_PARAMS.get(key, OTHER_PARAM)


# --- command-line argument types -----------------------------------------------------------
def arg(allowed: Range):
    """An argparse ``type=`` that checks ``allowed``: argparse then says ``argument --flag: must be ...``."""

    def parse(text: str):
        try:
            return allowed.check(text, "value")
        except CmrtError as exc:
            raise argparse.ArgumentTypeError(str(exc).removeprefix("value ")) from None

    parse.__name__ = "integer" if allowed.integer else "number"
    return parse


def run_id_arg(text: str) -> int:
    """argparse type of a run id (1 <= id < 2**63)."""
    return arg(RUN_ID)(text)


# --- input files ----------------------------------------------------------------------------
def read_text(path: str | os.PathLike, what: str, max_bytes: int = MAX_FILE_BYTES) -> str:
    """A user's input file as text: a regular file (a FIFO, a device, a socket or a directory is refused
    without blocking), at most ``max_bytes``, UTF-8."""
    where = f"{what} {shown(os.fspath(path))}"
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise CmrtError(f"cannot read {where}: {exc.strerror or exc}") from None
    except ValueError:  # an embedded NUL
        raise CmrtError(f"cannot read {where}: not a valid path") from None
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise CmrtError(f"cannot read {where}: it is a directory")
        if not stat.S_ISREG(st.st_mode):
            raise CmrtError(f"cannot read {where}: not a regular file (a FIFO, device or socket)")
        if st.st_size > max_bytes:
            raise CmrtError(f"cannot read {where}: larger than {max_bytes} bytes")
        chunks, size = [], 0
        while size <= max_bytes:
            chunk = os.read(fd, max_bytes + 1 - size)
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        data = b"".join(chunks)
    except OSError as exc:
        raise CmrtError(f"cannot read {where}: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if len(data) > max_bytes:
        raise CmrtError(f"cannot read {where}: larger than {max_bytes} bytes")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise CmrtError(f"{where} is not UTF-8 text (byte {exc.start})") from None


_TOML_TOKENS = re.compile(r'"""(?:[^\\]|\\.)*?"""|\'\'\'.*?\'\'\'|"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'|#[^\n]*|[\[\]{}]',
                          re.DOTALL)
_JSON_TOKENS = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{}]', re.DOTALL)


def check_nesting(text: str, where: str, tokens: re.Pattern = _JSON_TOKENS, limit: int = MAX_NESTING) -> None:
    """CmrtError if brackets/braces outside strings and comments nest deeper than ``limit``."""
    if text.count("[") + text.count("{") <= limit:
        return
    depth = 0
    for m in tokens.finditer(text):
        c = m.group()
        if c in "[{":
            depth += 1
            if depth > limit:
                raise CmrtError(f"{where}: nested deeper than {limit} levels")
        elif c in "]}":
            depth -= 1


def check_dotted_keys(text: str, where: str, limit: int = MAX_NESTING) -> None:
    """Refuse a TOML key of more than ``limit`` dotted parts before tomllib sees it: tomllib's time and
    memory grow with the square of a dotted key's length (a 400 kB file with one such key reached 23.9 GB).
    The keys of a line are what precedes each ``=`` (inline tables too; a table header: the whole line);
    no cmrt file nests keys deeper than its brackets may nest."""
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.lstrip()
        keys = [stripped] if stripped.startswith("[") else stripped.split("=")[:-1]
        if any(key.count(".") >= limit for key in keys):
            raise CmrtError(f"{where}: line {number}: a key of more than {limit} dotted parts")


def parse_toml(text: str, where: str) -> dict:
    """TOML text -> dict; one-line CmrtError naming ``where`` on any malformation."""
    check_nesting(text, where, _TOML_TOKENS)
    check_dotted_keys(text, where)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CmrtError(f"malformed {where}: {exc}") from None
    except RecursionError:
        raise CmrtError(f"{where}: nested too deep") from None
    except ValueError as exc:  # an integer past Python's int-string limit
        raise CmrtError(f"malformed {where}: {str(exc).split(':')[0]}") from None


def _no_constant(name: str):
    raise CmrtError(f"{name} is not a number (JSON values must be finite)")


def parse_json(text: str, where: str):
    """JSON text -> value; NaN/Infinity refused; one-line CmrtError naming ``where``."""
    check_nesting(text, where)
    try:
        return json.loads(text, parse_constant=_no_constant)
    except CmrtError as exc:
        raise CmrtError(f"{where}: {exc}") from None
    except json.JSONDecodeError as exc:
        raise CmrtError(f"{where} is not JSON: {exc}") from None
    except RecursionError:
        raise CmrtError(f"{where}: nested too deep") from None
    except ValueError as exc:  # an integer past Python's int-string limit
        raise CmrtError(f"{where} is not JSON: {str(exc).split(':')[0]}") from None


def load_toml(path: str | os.PathLike, what: str) -> dict:
    """A TOML input file (checked as :func:`read_text`) parsed."""
    return parse_toml(read_text(path, what), f"{what} {shown(os.fspath(path))}")


# --- JSON output -----------------------------------------------------------------------------
def json_safe(value):
    """``value`` with every non-finite float as None (JSON has no NaN or Infinity), tuples as lists."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if hasattr(value, "item") and hasattr(value, "dtype"):  # a numpy scalar
        return json_safe(value.item())
    return value


def dumps(value, indent: int | None = None) -> str:
    """JSON text that never contains NaN or Infinity (they become null)."""
    return json.dumps(json_safe(value), indent=indent, allow_nan=False)


# --- output files -----------------------------------------------------------------------------
_SQLITE_MAGIC = b"SQLite format 3\x00"


def _never_replaced(target: Path, reading: Iterable[str | os.PathLike]) -> str | None:
    """Why an existing ``target`` may never be written over, even with ``--force``, or None: it is a file the
    command reads, an SQLite database (a store, whatever its name) or a TOML file (a task or sequence file:
    cmrt never writes TOML, so such a target is a user's own file given by mistake)."""
    for other in reading:
        with contextlib.suppress(OSError):
            if os.path.samefile(target, other):
                return "it is a file this command reads"
    try:
        with open(target, "rb") as fh:
            head = fh.read(len(_SQLITE_MAGIC))
    except OSError:
        head = b""
    if head == _SQLITE_MAGIC:
        return "it is an SQLite database (a store?)"
    if target.suffix.lower() == ".toml":
        return "it is a TOML file (a task or sequence file?)"
    return None


def check_output(path: str | os.PathLike, flag: str, suffixes: tuple[str, ...] = (), *, replace: bool = True,
                 reading: Iterable[str | os.PathLike] = ()) -> Path:
    """Where ``path`` will be written, checked before any work: a usable name, an existing directory in which
    a file can be created, and no existing target that is not a regular file (a directory, a device, a FIFO,
    a symlink to one). Symlinks to regular files are followed: the file they point to is replaced.

    An existing regular file is replaced only with ``replace`` (the CLI passes ``--force``; the Python API
    replaces, as ``savefig`` does), and never when :func:`_never_replaced` says why not (``reading``: the
    files the command reads)."""
    raw = os.fspath(path)
    where = f"{flag} {shown(raw)}"
    if not raw or "\0" in raw or len(raw) > 4096:
        raise CmrtError(f"cannot write {where}: not a valid path")
    target = Path(os.path.realpath(raw))
    try:
        st = os.stat(target)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise CmrtError(f"cannot write {where}: {exc.strerror or exc}") from None
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise CmrtError(f"cannot write {where}: it is a directory")
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise CmrtError(f"cannot write {where}: not a regular file")
    if st is not None and (why := _never_replaced(target, reading)):
        raise CmrtError(f"will not write {where}: {why}")
    if suffixes and Path(raw).suffix.lower() not in suffixes:
        raise CmrtError(f"{flag} must end in {' or '.join(suffixes)}, got {shown(raw)}")
    if st is not None and not replace:
        raise CmrtError(f"will not write {where}: it exists (add --force to replace it)")
    parent = target.parent
    if not parent.is_dir():
        raise CmrtError(f"cannot write {where}: directory {shown(str(parent))} does not exist")
    try:  # can a file be created there? (root passes os.access everywhere; /proc still refuses)
        fd, probe = tempfile.mkstemp(dir=parent, prefix=f".{target.name[:40]}.", suffix=".probe")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise CmrtError(f"cannot write {where}: {exc.strerror or exc}") from None
    return target


def output_dir(path: str | os.PathLike, flag: str) -> Path:
    """A directory to write files into (created if missing), checked before any work: files can be created
    in it."""
    raw = os.fspath(path)
    where = f"{flag} {shown(raw)}"
    if not raw or "\0" in raw or len(raw) > 4096:
        raise CmrtError(f"cannot write {where}: not a valid path")
    out = Path(raw)
    if os.path.lexists(raw) and not out.is_dir():
        raise CmrtError(f"cannot write {where}: not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=out, prefix=".cmrt-", suffix=".probe")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise CmrtError(f"cannot write {where}: {exc.strerror or exc}") from None
    return out


def _mode_for(target: Path) -> int:
    try:
        return stat.S_IMODE(os.stat(target).st_mode)
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def _write_error(where: str, exc: OSError) -> Exception:
    """A failed write of an output: a full disk is a fault of the machine (DiskFull, exit 75), else bad input."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return DiskFull(f"cannot write {where}: disk full (free some space and run it again)")
    return CmrtError(f"cannot write {where}: {exc.strerror or exc}")


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, flag: str, suffixes: tuple[str, ...] = ()) -> Iterator[Path]:
    """Yield a temporary path next to ``path``'s target (same suffix, so writers pick the right format);
    when the block ends without an exception the file is synced and moved over the target. Any OSError
    (disk full, ...) becomes one CmrtError line; the temporary file never stays behind."""
    target = check_output(path, flag, suffixes)
    where = f"{flag} {shown(os.fspath(path))}"
    try:
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name[:40]}.", suffix=target.suffix)
        os.close(fd)
    except OSError as exc:
        raise _write_error(where, exc) from None
    try:
        yield Path(tmp)
        if os.path.getsize(tmp) == 0:
            raise CmrtError(f"cannot write {where}: nothing was written")
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, _mode_for(target))
        os.replace(tmp, target)
    except OSError as exc:
        raise _write_error(where, exc) from None
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp)


def write_text(path: str | os.PathLike, text: str, flag: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (:func:`atomic_output`)."""
    with atomic_output(path, flag) as tmp:
        tmp.write_bytes(text.encode("utf-8"))
    return Path(path)


def parse_sets(items: list[str] | None) -> dict[str, str]:
    """``--set KEY=VALUE`` options: KEY a parameter name, VALUE a finite number (``Task.with_params`` checks
    its range and shows the text as given)."""
    out = {}
    if len(items or []) > MAX_SETS:
        raise CmrtError(f"at most {MAX_SETS} --set options")
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise CmrtError(f"--set expects KEY=VALUE, got {shown(item)}")
        key = param_name(key.strip(), "--set KEY")
        number(value.strip(), f"--set {key}")
        out[key] = value.strip()
    return out
