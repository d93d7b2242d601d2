"""An installed cmrt (a wheel, not this checkout) carries everything it reads at run time."""

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "cmrt"


@pytest.mark.slow
def test_the_wheel_ships_every_task_sequence_and_asset(tmp_path):
    """``pip install .`` installs the wheel built here: if a task file were not package data, an installed
    ``cmrt tasks`` would list nothing (the bug this guards against)."""
    src = tmp_path / "src"  # a clean copy: a checkout's cmrt.egg-info/SOURCES.txt would hide a missing pattern
    shutil.copytree(PACKAGE, src / "cmrt", ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(tmp_path), str(src)],
                   check=True, capture_output=True)
    (wheel,) = tmp_path.glob("cmrt-*.whl")
    shipped = set(zipfile.ZipFile(wheel).namelist())
    needed = {str(p.relative_to(ROOT)) for p in PACKAGE.rglob("*")  # every module and data file of every layer
              if p.is_file() and "__pycache__" not in p.parts and p.name != "README.md"}
    assert {"cmrt/motion/tasks/bend.toml", "cmrt/motion/tasks/sequences/four-poses.toml", "cmrt/body/humanoid.xml",
            "cmrt/motion/library.json", "cmrt/cli/__main__.py"} <= needed
    assert needed <= shipped, sorted(needed - shipped)
    (entry_points,) = [n for n in shipped if n.endswith(".dist-info/entry_points.txt")]
    script = zipfile.ZipFile(wheel).read(entry_points).decode()
    assert "cmrt = cmrt.cli.launch:main" in script  # the console script's target exists (below)
    from cmrt.cli.launch import main

    assert callable(main)


def test_tasks_are_found_through_the_package_not_the_working_directory(tmp_path, monkeypatch):
    """Loading by name does not depend on where cmrt is run from."""
    monkeypatch.chdir(tmp_path)
    from cmrt.motion.taskfile import available_tasks, load_task

    assert {"bend", "catch", "punch", "push", "rise"} <= set(available_tasks())
    assert load_task("bend").name == "bend"
