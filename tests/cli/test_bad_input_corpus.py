"""A table of bad inputs across every verb and store kind: each is refused with exit 2, one escaped line on
stderr naming the flag or file, no traceback, within seconds, and the store byte-identical.

In-process (``cmrt.cli.main``), so the table runs in seconds. Rows with ``refuse=False`` are reads that may
succeed (a rollback-journal or old-schema store): the store must stay byte-identical, nothing converted.
"""

from __future__ import annotations

import os
import shutil
import sqlite3
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.input_helpers import assert_refused, call, make_old_store, make_store, snapshot


@dataclass(frozen=True)
class Case:
    argv: tuple[str, ...]
    store: str = "good"  # kind of --store file (STORE_KINDS)
    words: str | None = None  # must appear in the error line
    xfail: str | None = None
    refuse: bool = True  # False: only "store unchanged, no traceback, at most one line"

    @property
    def id(self) -> str:
        text = " ".join(self.argv).replace("{d}/", "")
        return f"{self.store}:{text}"[:90]


# --- the files the cases point at (written once per module into {d}) ----------------------------------
POSE = "[params]\nduration_s = 0.5\n[end_pose_deg]\nhip = -10\n"
TASK_FILES: dict[str, str | bytes] = {
    "params_int.toml": "params = 5\n",
    "params_array.toml": "[[params]]\nclip_s = 1\n",
    "params_string.toml": 'params = "clip_s=2"\n',
    "ranges_strings.toml": '[param_ranges]\nclip_s = ["a", "b"]\n',
    "ranges_one.toml": "[param_ranges]\nclip_s = [1]\n",
    "ranges_reversed.toml": "[param_ranges]\nclip_s = [3.0, 1.0]\n",
    "ranges_nan.toml": "[param_ranges]\nclip_s = [nan, 3.0]\n",
    "ranges_unknown.toml": "[param_ranges]\nmass = [1, 2]\n",
    "speed_list.toml": 'speed_param = ["duration_s"]\n',
    "speed_unknown.toml": 'speed_param = "mass"\n',
    "joint_unknown.toml": 'balance_joint = "tail"\n' + POSE,
    "joint_number.toml": "balance_joint = 3\n" + POSE,
    "reference_unknown.toml": 'reference = "zmp"\n',
    "reference_number.toml": "reference = 3\n",
    "hip_nan.toml": "[params]\nduration_s = 0.5\n[end_pose_deg]\nhip = nan\n",
    "hip_inf.toml": "[params]\nduration_s = 0.5\n[end_pose_deg]\nhip = -inf\n",
    "hip_string.toml": '[params]\nduration_s = 0.5\n[end_pose_deg]\nhip = "deep"\n',
    "hip_bool.toml": "[params]\nduration_s = 0.5\n[end_pose_deg]\nhip = true\n",
    "hip_huge.toml": "[params]\nduration_s = 0.5\n[end_pose_deg]\nhip = 1e6\n",
    "pose_table.toml": "end_pose_deg = 4\n[params]\nduration_s = 0.5\n",
    "clip_1e308.toml": "[params]\nclip_s = 1e308\n",
    "clip_nan.toml": "[params]\nclip_s = nan\n",
    "clip_inf.toml": "[params]\nclip_s = inf\n",
    "clip_negative.toml": "[params]\nclip_s = -1.0\n",
    "clip_zero.toml": "[params]\nclip_s = 0\n",
    "clip_digits.toml": "[params]\nclip_s = " + "9" * 5000 + "\n",
    "clip_long.toml": "[params]\nclip_s = 100.0\n",
    "clip_bigint.toml": "[params]\nclip_s = 99999999999999999999999999\n",
    "tail_short.toml": "[params]\ntail_s = 0.1\n",
    "tail_huge.toml": "[params]\ntail_s = 1e9\n",
    "duration_nan.toml": POSE.replace("0.5", "nan"),
    "duration_bool.toml": POSE.replace("0.5", "true"),
    "step_zero.toml": "[params]\ncop_sample_step_s = 0\n",
    "lag_two.toml": "[params]\nmax_tracking_lag = 2.0\n",
    "push_huge.toml": "[params]\npush_force_n = 1e300\n",
    "push_start_inf.toml": "[params]\npush_start_s = -inf\n",
    "timing_reversed.toml": POSE + "[timing]\nhip = [0.5, 0.2]\n",
    "timing_bools.toml": POSE + "[timing]\nhip = [false, true]\n",
    "timing_string.toml": POSE + '[timing]\nhip = "early"\n',
    "timing_nan.toml": POSE + "[timing]\nhip = [nan, 1.0]\n",
    "prop_string.toml": 'prop = "ball"\n',
    "prop_anvil.toml": '[prop]\nkind = "anvil"\n',
    "prop_extra.toml": '[prop]\nkind = "ball"\nmass = 3\n',
    "ball_massless.toml": '[prop]\nkind = "ball"\n[params]\nball_mass_kg = 0\n',
    "slab_flat.toml": '[prop]\nkind = "slab"\n[params]\nslab_thickness_m = 0\n',
    "slab_negative.toml": '[prop]\nkind = "slab"\n[params]\nslab_height_m = -1\n',
    "wall_stiff.toml": '[prop]\nkind = "wall"\n[params]\nwall_timeconst_s = 0\n',
    "robust_yes.toml": '[robust]\nenabled = "yes"\n',
    "robust_moment_nan.toml": "[robust]\npush_moments = [nan]\n",
    "robust_moments_many.toml": "[robust]\npush_moments = [" + ", ".join(["0.5"] * 100) + "]\n",
    "robust_weight.toml": "[robust]\nworst_weight = 2.0\n",
    "robust_array.toml": "robust = [1, 2]\n",
    "unknown_key.toml": "parms = 3\n",
    "name_number.toml": "name = 5\n",
    "summary_list.toml": "summary = [1]\n",
    "key_control.toml": '[params]\n"clip\\u0000s" = 1.0\n',
    "via_no_fraction.toml": POSE + "[via_pose_deg]\nhip = -5\n",
    "unbalanceable.toml": "[params]\nduration_s = 0.5\n[end_pose_deg]\nhip = -300\nlumbar = 300\n",
    "deep.toml": "a = " + "[" * 100_000 + "]" * 100_000 + "\n",
    "deep_inline.toml": "a = " + "{b = " * 50 + "1" + "}" * 50 + "\n",
    # tomllib's memory is quadratic in a dotted key (red team: 400 kB reached 23.9 GB); refused before parsing
    "dotted_key.toml": "[params]\na" + ".a" * 200_000 + " = 1\n",
    "dotted_header.toml": "[a" + ".a" * 200_000 + "]\n",
    "dotted_inline.toml": "x = {a" + ".a" * 200_000 + " = 1}\n",
    "not_utf8.toml": b"name = \"\xff\xfe\"\n",
    "malformed.toml": "name = \n",
    "nul.toml": b"name = \"a\x00b\"\n",
}
CURVE_FILES: dict[str, str | bytes] = {
    "c_list.json": "[1, 2]",
    "c_nan.json": '{"clip_s": 2.6, "knot_times_s": [0.5, 1, 1.5, 2], "values_m": [0, NaN, 0, 0]}',
    "c_inf.json": '{"clip_s": 2.6, "knot_times_s": [0.5, 1, 1.5, 2], "values_m": [0, 0, 0, 1e400]}',
    "c_huge_value.json": '{"clip_s": 2.6, "knot_times_s": [0.5, 1, 1.5, 2], "values_m": [0, 5, 0, 0]}',
    "c_unsorted.json": '{"clip_s": 2.6, "knot_times_s": [1, 0.5, 1.5, 2], "values_m": [0, 0, 0, 0]}',
    "c_three.json": '{"clip_s": 2.6, "knot_times_s": [0.5, 1, 1.5], "values_m": [0, 0, 0]}',
    "c_strings.json": '{"clip_s": "2.6", "knot_times_s": [0.5, 1, 1.5, 2], "values_m": [0, 0, 0, 0]}',
    "c_bools.json": '{"clip_s": 2.6, "knot_times_s": [0.5, 1, 1.5, 2], "values_m": [true, 0, 0, 0]}',
    "c_extra.json": '{"clip_s": 2.6, "knot_times_s": [0.5, 1, 1.5, 2], "values_m": [0, 0, 0, 0], "x": 1}',
    "c_clip.json": '{"clip_s": 3.0, "knot_times_s": [0.5, 1, 1.5, 2], "values_m": [0, 0, 0, 0]}',
    "c_clip_huge.json": '{"clip_s": 1e9, "knot_times_s": [0.5, 1, 1.5, 2], "values_m": [0, 0, 0, 0]}',
    "c_digits.json": '{"clip_s": ' + "9" * 5000 + "}",
    "c_deep.json": "[" * 100_000 + "]" * 100_000,
    "c_deep_obj.json": '{"a": ' * 40 + "1" + "}" * 40,
    "c_not_json.json": "{not json",
    "c_empty.json": "",
    "c_not_utf8.json": b"\xff\xfe{}",
    "c_wrapped.json": '{"cmrt": [1]}',
}
SEQ = '[[motion]]\ntask = "bend"\nspeed = 0.5\nstart_s = {start}\n'
SEQUENCE_FILES: dict[str, str | bytes] = {
    "s_start_nan.toml": SEQ.format(start="nan"),
    "s_start_inf.toml": SEQ.format(start="inf"),
    "s_start_string.toml": SEQ.format(start='"soon"'),
    "s_start_negative.toml": SEQ.format(start="-1.0"),
    "s_speed_nan.toml": SEQ.format(start="1.0").replace("0.5", "nan"),
    "s_speed_string.toml": SEQ.format(start="1.0").replace("0.5", '"fast"'),
    "s_tail_nan.toml": "tail_s = nan\n" + SEQ.format(start="1.0"),
    "s_tail_inf.toml": "tail_s = inf\n" + SEQ.format(start="1.0"),
    "s_tail_string.toml": 'tail_s = "long"\n' + SEQ.format(start="1.0"),
    "s_no_motion.toml": 'name = "x"\n',
    "s_motion_table.toml": "[motion]\ntask = 'bend'\n",
    "s_motion_missing.toml": '[[motion]]\ntask = "bend"\n',
    "s_task_number.toml": SEQ.format(start="1.0").replace('"bend"', "7"),
    "s_task_unknown.toml": SEQ.format(start="1.0").replace("bend", "nope"),
    "s_overlap.toml": SEQ.format(start="1.0") + SEQ.format(start="1.1").replace("bend", "rise"),
    "s_too_long.toml": SEQ.format(start="58.0"),
    "s_unknown_key.toml": "color = 1\n" + SEQ.format(start="1.0"),
    "s_not_utf8.toml": b"name = \"\xff\"\n",
    "s_deep.toml": "x = " + "[" * 100_000 + "]" * 100_000 + "\n",
    "s_dotted_key.toml": "a" + ".a" * 200_000 + " = 1\n" + SEQ.format(start="1.0"),
}


def _write(d: Path, files: dict[str, str | bytes]) -> None:
    for name, content in files.items():
        (d / name).write_bytes(content if isinstance(content, bytes) else content.encode("utf-8"))


@pytest.fixture(scope="module")
def inputs_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("inputs")
    _write(d, TASK_FILES)
    _write(d, CURVE_FILES)
    _write(d, SEQUENCE_FILES)
    for name in ("fifo.toml", "fifo.json"):
        os.mkfifo(d / name)
    for name in ("dir.toml", "dir.json", "outdir"):
        (d / name).mkdir()
    (d / "big.toml").write_bytes(b"#" * 1_100_000)
    (d / "big.json").write_bytes(b" " * 1_100_000)
    os.symlink("/dev/full", d / "full.png")
    os.symlink("/dev/full", d / "full.npz")
    os.symlink("/dev/full", d / "full.json")
    os.symlink("/dev/full", d / "full.mp4")
    return d


@pytest.fixture(scope="module")
def template_store(tmp_path_factory) -> Path:
    return make_store(tmp_path_factory.mktemp("template") / "store.sqlite")


def _flip(data: bytes, offset: int) -> bytes:
    b = bytearray(data)
    b[offset] ^= 0xFF
    return bytes(b)


def make_kind(kind: str, path: Path, template: Path) -> Path:
    """A --store of ``kind`` at ``path``."""
    good = template.read_bytes()
    if kind == "good":
        path.write_bytes(good)
    elif kind == "missing":
        pass
    elif kind == "directory":
        path.mkdir()
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "text":
        path.write_text("not a database\n")
    elif kind == "foreign":
        con = sqlite3.connect(path)
        con.execute("CREATE TABLE t (x)")
        con.commit()
        con.close()
    elif kind == "truncated":
        path.write_bytes(good[: len(good) // 2])
    elif kind == "flipped-header":  # a byte of the SQLite header's page size
        path.write_bytes(_flip(good, 16))
    elif kind == "flipped-page":  # the b-tree page type of a table page: "database disk image is malformed"
        path.write_bytes(_flip(good, 3 * 4096))
    elif kind == "flipped-row":  # one byte of every run's parameters JSON, still UTF-8: rows no longer decode
        path.write_bytes(good.replace(b'{"clip_s"', b'x"clip_s"'))
    elif kind == "readonly":
        path.write_bytes(good)
        path.chmod(0o444)
    elif kind == "journal-delete":  # a store copied from a cmrt that used the rollback journal
        path.write_bytes(good)
        con = sqlite3.connect(path)
        con.execute("PRAGMA journal_mode = DELETE")
        con.close()
    elif kind == "old-schema":
        make_old_store(path, 2)
    elif kind == "fifo":
        os.mkfifo(path)
    else:
        raise ValueError(kind)
    return path


# --- the table ----------------------------------------------------------------------------------------------
def _cases() -> list[Case]:
    cases: list[Case] = []
    add = cases.append
    # task files, rotated over the verbs that take a task: the error names the file
    task_verbs = [
        lambda f: ("simulate", f),
        lambda f: ("submit", f),
        lambda f: ("optimize", f, "--max-evals", "10", "--no-progress"),
        lambda f: ("best", f),
        lambda f: ("render", f, "--out", "{d}/o.png"),
        lambda f: ("interpolate", f, "--speed", "0.5"),
        lambda f: ("bench", "--task", f, "--backends", "batch"),
        lambda f: ("plot", "--family", f, "--out-dir", "{d}/outdir"),
        lambda f: ("check", f),
    ]
    names = list(TASK_FILES) + ["fifo.toml", "dir.toml", "big.toml", "missing.toml"]
    for i, name in enumerate(names):
        add(Case(task_verbs[i % len(task_verbs)]("{d}/" + name), words=name))
    add(Case(("simulate", "/dev/stdin.toml"), words="stdin"))
    add(Case(("submit", "nosuchtask"), words="unknown task"))
    add(Case(("check", "walk"), words="cannot check"))
    add(Case(("submit", "bend\x1b[2J"), words="unknown task"))
    add(Case(("simulate", ""), words="task"))
    add(Case(("simulate", "bend", "--reference", "zmp"), words="--reference"))
    add(Case(("optimize", "bend", "--reference", "", "--no-progress"), words="--reference"))
    # curve files and --curve / --compare specs
    for name in [*CURVE_FILES, "fifo.json", "dir.json", "big.json", "missing.json"]:
        add(Case(("simulate", "bend", "--curve", "{d}/" + name), words=name))
    for spec in ("²", "٣", "1e3", "-1", "0", str(2**63), str(2**64), "nope", "zero\n", "/dev/zero", "/dev/stdin"):
        add(Case(("simulate", "bend", "--curve", spec), words="--curve" if spec not in ("/dev/zero", "/dev/stdin")
                 else "not a regular file"))
    add(Case(("simulate", "bend", "--curve", "99"), words="no run 99"))
    add(Case(("simulate", "bend", "--curve", "2"), words="no result"))
    add(Case(("render", "bend", "--compare", "{d}/c_nan.json", "--out", "{d}/o.png"), words="c_nan.json"))
    add(Case(("render", "bend", "--compare", "²", "--out", "{d}/o.png"), words="--compare"))
    add(Case(("simulate", "bend", "--speed", "0.6", "--curve", "library", "--set", "clip_s=3"), words="clip"))
    # --set
    for item, words in [
        ("clip_s=nan", "clip_s"), ("clip_s=inf", "clip_s"), ("clip_s=1e5", "clip_s"), ("clip_s=1e9", "clip_s"),
        ("clip_s=-1", "clip_s"), ("clip_s=", "clip_s"), ("duration_s=fast", "duration_s"),
        ("duration_s=²", "duration_s"), ("duration_s=٣", "duration_s"), ("foo\nbar=1", "--set"),
        ("=1", "--set"), ("nokey", "KEY=VALUE"), ("mass=3", "no parameter"), ("clip_s=1_0", "clip_s"),
        ("clip_s=0x10", "clip_s"), ("tail_s=0", "tail_s"), ("push_force_n=1e300", "push_force_n"),
        ("clip_s=" + "9" * 5000, "clip_s"), ("a b=1", "--set"), ("stand_s=59.9", "no parameter"),
        ("clip_s=59.9", "longer than"), ("duration_s=3", "range"), ("preparation_s=2.5", "exceeds"),
        ("cop_sample_step_s=0", "cop_sample_step_s"),
    ]:
        verb = ("simulate", "submit", "best", "interpolate")[len(cases) % 4]
        add(Case((verb, "bend", "--set", item), words=words))
    add(Case(("submit", "push", "--set", "slab_thickness_m=0"), words="slab_thickness_m"))
    add(Case(("simulate", "catch", "--set", "ball_mass_kg=0"), words="ball_mass_kg"))
    add(Case(("simulate", "punch", "--set", "wall_timeconst_s=0"), words="wall_timeconst_s"))
    add(Case(("render", "push", "--set", "slab_height_m=-1", "--out", "{d}/o.png"), words="slab_height_m"))
    add(Case(("bench", "--set", "clip_s=1e9", "--backends", "batch"), words="clip_s"))
    # every number on the command line
    for verb in ("submit", "optimize"):
        extra = ("--no-progress",) if verb == "optimize" else ()
        for flag, value in [
            ("--seed", "-1"), ("--seed", str(2**63)), ("--seed", str(2**64)), ("--seed", "1.5"), ("--seed", "²"),
            ("--sigma0", "nan"), ("--sigma0", "inf"), ("--sigma0", "0"), ("--sigma0", "1e9"),
            ("--popsize", "1"), ("--popsize", "1000000"), ("--max-evals", "0"), ("--max-evals", "1e12"),
            ("--min-evals", "-1"), ("--stall-generations", "0"), ("--init", "²"), ("--init", "0"),
            ("--init", str(2**64)), ("--speed", "nan"), ("--speed", "9"),
        ]:
            add(Case((verb, "bend", flag, value, *extra), words=flag))
    add(Case(("submit", "bend", "--init", "99"), words="no run 99"))
    add(Case(("submit", "bend", "--robust", "--sigma0", "-inf"), words="--sigma0"))
    add(Case(("optimize", "bend", "--speeds", "0.4,nan", "--no-progress"), words="--speeds"))
    add(Case(("optimize", "bend", "--speeds", "a,b", "--no-progress"), words="--speeds"))
    add(Case(("optimize", "bend", "--speeds", ",".join(["0.5"] * 40), "--no-progress"), words="--speeds"))
    add(Case(("optimize", "bend", "--speeds", "0.4,9", "--no-progress"), words="range"))
    add(Case(("optimize", "bend", "--speeds", "0.4,0.5", "--family-sigma0", "-1"), words="--family-sigma0"))
    add(Case(("optimize", "bend", "--speeds", "0.4,0.5", "--family-sigma0", "nan"), words="--family-sigma0"))
    add(Case(("optimize", "bend", "--workers", "0", "--no-progress"), words="--workers"))
    add(Case(("optimize", "bend", "--backend", "gpu"), words="--backend"))
    for value in ("nan", "0", "-1", "inf", "1e400"):
        add(Case(("worker", "--until-idle", "--stale-after", value), words="--stale-after"))
    add(Case(("worker", "--until-idle", "--workers", "1000"), words="--workers"))
    add(Case(("worker", "--once", "--backend", "nope"), words="--backend"))
    # run ids
    for verb in ("show", "export", "plot"):
        for rid in ("0", "-1", str(2**63), "²", "٣", "1e3", " ", "1_0"):
            add(Case((verb, rid), words="run"))
    add(Case(("show", "99"), words="no run 99"))
    add(Case(("export", "99"), words="no run 99"))
    add(Case(("plot", "2", "--out-dir", "{d}/outdir"), words="no result"))
    add(Case(("export", "1", "--format", "xml"), words="--format"))
    add(Case(("jobs", "--status", "weird"), words="--status"))
    add(Case(("runs", "--bogus"), words="unrecognized"))
    add(Case(("tasks", "extra"), words="unrecognized"))
    add(Case(("tasks", "\x1b[31m"), words="unrecognized"))
    add(Case(("frobnicate",), words="invalid choice"))
    add(Case(("best", "bend", "--speed", "0.5"), words="no finished run"))
    add(Case(("best", "stand", "--speed", "0.4"), words="no speed"))
    # output paths: checked before any simulation, never a false "wrote"
    for path, words in [("/proc/x{ext}", "No such file"), ("{d}/outdir", "directory"),
                        ("{d}/full{ext}", "not a regular file"), ("{d}/nodir/x{ext}", "does not exist"),
                        ("", "not a valid path")]:
        add(Case(("simulate", "bend", "--trace", path.format(d="{d}", ext=".npz")), words=words))
        add(Case(("render", "bend", "--out", path.format(d="{d}", ext=".png")), words=words))
        add(Case(("export", "1", "--out", path.format(d="{d}", ext=".json")), words=words))
        add(Case(("interpolate", "bend", "--speed", "0.5", "--out", path.format(d="{d}", ext=".json")), words=words))
        add(Case(("sequence", "four-poses", "--trace", path.format(d="{d}", ext=".npz")), words=words))
    add(Case(("render", "bend", "--out", "{d}/full.mp4"), words="not a regular file"))
    add(Case(("render", "bend", "--out", "{d}/x.gif"), words=".png or .mp4"))
    add(Case(("render", "bend", "--frames", "0", "--out", "{d}/o.png"), words="--frames"))
    add(Case(("render", "bend", "--fps", "1e9", "--out", "{d}/o.mp4"), words="--fps"))
    add(Case(("plot", "1", "--out-dir", "/proc/x"), words="--out-dir"))
    add(Case(("plot", "1", "--out", "{d}/plots"), words="give --out-dir DIR"))
    add(Case(("plot", "1", "--out-dir", "{d}/c_list.json"), words="directory the figures go into"))
    add(Case(("plot", "--family", "bend", "--out-dir", "/dev/full"), words="not a directory"))
    add(Case(("plot",), words="plot what"))
    add(Case(("plot", "--family", "stand", "--out-dir", "{d}/outdir"), words="no speed parameter"))
    add(Case(("plot", "--family", "nosuch", "--out-dir", "{d}/outdir"), words="unknown task"))
    add(Case(("plot", "--sequence", "{d}/fifo.toml", "--out-dir", "{d}/outdir"), words="fifo.toml"))
    add(Case(("plot", "--sequence", "{d}/s_start_nan.toml", "--out-dir", "{d}/outdir"), words="start_s"))
    # sequences
    for name in [*SEQUENCE_FILES, "fifo.toml", "dir.toml", "missing.toml"]:
        add(Case(("sequence", "{d}/" + name), words=name))
    add(Case(("sequence", "nope"), words="unknown sequence"))
    add(Case(("sequence", "/dev/stdin"), words="unknown sequence"))
    add(Case(("sequence", "four-poses", "--curve", "library"), words="--curve"))
    # interpolate, bench
    add(Case(("interpolate", "bend", "--speed", "0.5", "--param", "a\nb"), words="--param"))
    add(Case(("interpolate", "bend", "--speed", "0.5", "--param", "mass"), words="no parameter"))
    add(Case(("interpolate", "stand"), words="no speed parameter"))
    add(Case(("interpolate", "bend", "--speed", "0.5", "--from", "web"), words="--from"))
    for flag, value in [("--population", "0"), ("--population", "1e9"), ("--repeat", "0"), ("--speed", "nan"),
                        ("--backends", "batch,nope"), ("--backends", "\x1b[2J"), ("--workers", "-1")]:
        add(Case(("bench", flag, value), words=flag))
    # store kinds: read verbs refuse what is not a CMRT store, without creating or changing anything
    reads = [("jobs",), ("runs",), ("show", "1"), ("best", "bend"), ("export", "1"),
             ("simulate", "bend", "--curve", "1"), ("interpolate", "bend", "--speed", "0.5", "--from", "store"),
             ("plot", "1", "--out-dir", "{d}/outdir")]
    for kind, words in [("missing", "no CMRT store"), ("directory", "directory"), ("empty", "empty"),
                        ("text", "not a CMRT store"), ("foreign", "not a CMRT store"),
                        ("truncated", "corrupted"), ("flipped-header", "corrupted"),
                        ("flipped-page", "damaged"), ("fifo", "regular file")]:
        for argv in reads:
            add(Case(argv, store=kind, words=words))
    writes = [("submit", "bend"), ("worker", "--until-idle"),
              ("optimize", "bend", "--max-evals", "10", "--no-progress")]
    for kind, words in [("directory", "directory"), ("text", "not a CMRT store"), ("foreign", "not a CMRT store"),
                        ("truncated", "corrupted"), ("fifo", "regular file")]:
        for argv in writes:
            add(Case(argv, store=kind, words=words))
    for kind in ("missing", "empty"):  # a run id as --init cannot be in a store that does not exist yet
        add(Case(("submit", "bend", "--init", "1"), store=kind))
        add(Case(("optimize", "bend", "--init", "1", "--no-progress"), store=kind))
    for argv in [("submit", "bend", "--seed", "-1"), ("show", "0"), ("export", "1", "--out", "/proc/x"),
                 ("worker", "--stale-after", "nan"), ("simulate", "bend", "--set", "clip_s=nan")]:
        add(Case(argv, store="readonly"))
        add(Case(argv, store="missing"))
    # store.py behaviour owned elsewhere: read verbs must not convert a store; rows must decode or be refused
    for kind in ("journal-delete", "old-schema"):
        for argv in (("jobs",), ("runs",), ("show", "1")):
            add(Case(argv, store=kind, refuse=False))  # read verbs open read-only: nothing converted
    for argv in (("jobs",), ("runs",), ("show", "1"), ("export", "1"), ("best", "bend")):
        add(Case(argv, store="flipped-row", words="damaged"))
    return cases


CASES = _cases()
XFAIL_COUNT = sum(1 for c in CASES if c.xfail)


def _param(c: Case):
    marks = [pytest.mark.xfail(strict=False, reason=c.xfail)] if c.xfail else []
    return pytest.param(c, id=c.id, marks=marks)


def test_the_corpus_is_big_and_covers_every_verb():
    verbs = {c.argv[0] for c in CASES}
    want = {"tasks", "simulate", "submit", "optimize", "worker", "jobs", "runs", "show", "best", "export",
            "interpolate", "sequence", "plot", "render", "bench", "check"}
    assert want <= verbs, want - verbs
    kinds = {c.store for c in CASES}
    assert {"missing", "directory", "empty", "text", "foreign", "truncated", "flipped-page", "readonly"} <= kinds
    assert len(CASES) - XFAIL_COUNT >= 150, len(CASES)


@pytest.mark.parametrize("case", [_param(c) for c in CASES])
def test_bad_input_is_refused(case: Case, inputs_dir, template_store, tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("CMRT_STORE", raising=False)
    monkeypatch.chdir(tmp_path)
    store = make_kind(case.store, tmp_path / "store.sqlite", template_store)
    argv = [a.replace("{d}", str(inputs_dir)) for a in case.argv] + ["--store", str(store)]
    before = snapshot(store)
    try:
        r = call(capsys, argv)
    finally:
        if case.store == "readonly":
            store.chmod(0o644)
    after = snapshot(store)
    if case.refuse:
        assert_refused(r, before[0], after[0], case.words)  # the store file itself: bytes, or absent
    else:
        assert before[0] == after[0] and "Traceback" not in r.err and len(r.err_lines) <= 1
    leftovers = [p.name for p in inputs_dir.iterdir() if p.name.startswith(".")]
    assert leftovers == [], f"temporary files left behind: {leftovers}"
    shutil.rmtree(tmp_path / "outdir", ignore_errors=True)


@pytest.mark.parametrize("kind", ["truncated", "flipped-header"])
def test_refusing_a_damaged_store_leaves_no_side_files(kind, template_store, tmp_path, capsys):
    store = make_kind(kind, tmp_path / "store.sqlite", template_store)
    before = snapshot(store)
    r = call(capsys, ["runs", "--store", str(store)])
    assert r.rc == 2 and snapshot(store) == before
