"""The note a first clip after an install prints while the controller's kernels compile (``cmrt.control.compiled``):
once per process, only when numba's cache does not hold them."""

import io

import cmrt.control.compiled as compiled
from cmrt.control import spatial_kernel


def test_numba_says_whether_the_kernels_are_cached():
    assert compiled.kernels_cached() in (True, False)  # this numba's cache layout is the one read


def test_numba_says_whether_the_3d_kernels_are_cached():
    assert compiled.kernels_cached(spatial_kernel.plan_step) in (True, False)


def test_the_note_is_printed_once_per_body_and_only_for_a_cold_cache(monkeypatch):
    out = io.StringIO()
    monkeypatch.setattr(compiled, "_noted", set())
    monkeypatch.setattr(compiled, "kernels_cached", lambda dispatcher=None: False)
    assert compiled.note_first_compile(out) and not compiled.note_first_compile(out)
    assert compiled.note_first_compile(out, spatial_kernel.plan_step)  # the 3D body's kernels: their own note
    assert not compiled.note_first_compile(out, spatial_kernel.plan_step)
    assert out.getvalue().count("compiling the controller's kernels for this machine, once") == 2
    monkeypatch.setattr(compiled, "_noted", set())
    monkeypatch.setattr(compiled, "kernels_cached", lambda dispatcher=None: True)
    assert not compiled.note_first_compile(out)
    monkeypatch.setattr(compiled, "_noted", set())
    monkeypatch.setattr(compiled, "kernels_cached", lambda dispatcher=None: None)  # numba does not say: no guess
    assert not compiled.note_first_compile(out)
