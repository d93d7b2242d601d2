"""OpenGL only when rendering: a GL backend that cannot load breaks rendering alone, in one line."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

# PyOpenGL, when the library of its platform cannot be loaded (no libOSMesa, no EGL driver), fails on import
# with this AttributeError; MuJoCo's own import then failed with it whenever MUJOCO_GL named that backend.
BROKEN_OPENGL = 'raise AttributeError("\'NoneType\' object has no attribute \'glGetError\'")\n'


def _cmrt(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    broken = tmp_path / "broken"
    (broken / "OpenGL").mkdir(parents=True, exist_ok=True)
    (broken / "OpenGL" / "__init__.py").write_text(BROKEN_OPENGL)
    env = {**os.environ, "MUJOCO_GL": "egl", "PYTHONPATH": f"{broken}{os.pathsep}{ROOT}"}
    env.pop("CMRT_MUJOCO_GL", None)  # as in a fresh shell: the user's MUJOCO_GL is the request
    return subprocess.run([sys.executable, "-m", "cmrt.cli", *args, "--store", str(tmp_path / "s.sqlite")],
                          capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)


def test_simulating_needs_no_opengl(tmp_path):
    r = _cmrt(tmp_path, "simulate", "bend", "--speed", "0.6", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["task"] == "bend"


def test_rendering_without_a_loadable_backend_is_one_line_and_exit_2(tmp_path):
    r = _cmrt(tmp_path, "render", "bend", "--curve", "zero", "--out", str(tmp_path / "x.png"))
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("cmrt: error: cannot render: OpenGL backend egl")
    assert not (tmp_path / "x.png").exists()


def test_the_api_imports_no_opengl_until_it_renders():
    code = ("import sys, cmrt; t = cmrt.load_task('bend').with_speed(0.4); cmrt.evaluate(t, cmrt.simulate(t)); "
            "print('OpenGL' in sys.modules, sys.modules['mujoco'] is not None)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 0 and r.stdout.split() == ["False", "True"], r.stderr


@pytest.mark.slow  # a fresh process that renders
def test_a_script_that_imports_mujoco_first_still_renders_headless(tmp_path):
    """``import mujoco`` before cmrt with no MUJOCO_GL: MuJoCo picks GLFW, which needs a display. Without one
    cmrt loads its own backend (the in-process render tests failed after tests/control/conftest.py did this)."""
    out = tmp_path / "x.png"
    code = ("import mujoco, cmrt; from cmrt.viz.render import render; t = cmrt.load_task('bend').with_speed(0.4); "
            f"render(t, cmrt.Cmrt.zero(t.clip_s), {str(out)!r}, n_frames=2)")
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "CMRT_MUJOCO_GL", "DISPLAY")}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                       env={**env, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 0, r.stderr[-2000:]
    assert out.stat().st_size > 10_000
