"""The note a first clip after an install prints while the controller's kernels compile (``cmrt.control.compiled``):
once per process, only when numba's cache does not hold them."""

import io

import cmrt.control.compiled as compiled


def test_numba_says_whether_the_kernels_are_cached():
    assert compiled.kernels_cached() in (True, False)  # this numba's cache layout is the one read


def test_the_note_is_printed_once_and_only_for_a_cold_cache(monkeypatch):
    out = io.StringIO()
    monkeypatch.setattr(compiled, "_noted", False)
    monkeypatch.setattr(compiled, "kernels_cached", lambda: False)
    assert compiled.note_first_compile(out) and not compiled.note_first_compile(out)
    assert out.getvalue().count("compiling the controller's kernels for this machine, once") == 1
    monkeypatch.setattr(compiled, "_noted", False)
    monkeypatch.setattr(compiled, "kernels_cached", lambda: True)
    assert not compiled.note_first_compile(out)
    monkeypatch.setattr(compiled, "_noted", False)
    monkeypatch.setattr(compiled, "kernels_cached", lambda: None)  # numba does not say: no guess
    assert not compiled.note_first_compile(out)
