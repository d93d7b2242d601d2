"""Time a new user's first clip: a fresh virtual environment with ``pip install .``, then ``cmrt simulate`` twice
(the first compiles the controller's kernels, the second loads them from numba's cache).

    python tools/first_run.py                          # a fresh venv in a temp dir: install, first and second clip
    python tools/first_run.py --venv .venv             # this project's venv, numba's cache in a fresh temp dir
    python tools/first_run.py --venv .venv --warm-only # one clip with the cache as it is (the tools test)

README's first-run figure comes from the first form on the 2-core VM (docs/getting-started.md).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
NOTE = "compiling the controller's kernels"


def _timed(cmd: list[str], env: dict, cwd: Path) -> tuple[float, subprocess.CompletedProcess]:
    start = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=cwd, timeout=1800)
    if out.returncode not in (0, 1):
        raise SystemExit(f"first_run: {' '.join(cmd)} failed: {out.stderr.strip()[-500:]}")
    return time.perf_counter() - start, out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--venv", type=Path, help="an environment with cmrt installed (default: a fresh one, installed "
                    "here with pip)")
    ap.add_argument("--warm-only", action="store_true", help="one clip with numba's cache as it is")
    ap.add_argument("--task", default="bend")
    ap.add_argument("--speed", default="0.4")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    row: dict = {"machine": f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}"}
    with tempfile.TemporaryDirectory() as tmp:
        work, env = Path(tmp), {**os.environ, "CMRT_STORE": ""}
        env.pop("NUMBA_CACHE_DIR", None)
        if args.venv is None:
            venv = work / "venv"
            subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
            start = time.perf_counter()
            subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", str(ROOT)], check=True,
                           capture_output=True)
            row["install_s"] = round(time.perf_counter() - start, 1)
        else:
            venv = args.venv.resolve()
            if not args.warm_only:  # this environment's cache is warm: a cold one of its own
                env["NUMBA_CACHE_DIR"] = str(work / "numba-cache")
        cmd = [str(venv / "bin" / "cmrt"), "simulate", args.task, "--speed", args.speed, "--json"]
        runs = ["warm"] if args.warm_only else ["first", "second"]
        for name in runs:
            wall, out = _timed(cmd, env, work)
            row[f"{name}_s"] = round(wall, 1)
            row[f"{name}_noted_compile"] = NOTE in out.stderr
            row[f"{name}_success"] = json.loads(out.stdout)["success"]
    if args.json:
        print(json.dumps(row))
    else:
        print("; ".join(f"{k} {v}" for k, v in row.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
