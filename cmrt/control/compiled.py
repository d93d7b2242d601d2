"""Whether the controllers' compiled kernels (numba: the planar ``cmrt.control.kernel``, the 3D
``cmrt.control.spatial_kernel``) are in numba's cache, and a one-line note on stderr when they are not: the first clip
of a body after an install compiles its kernels for this machine (the planar about 30 s on the project's 2-core VM,
measured by ``tools/first_run.py``; the 3D about 20 s), every later one loads them in about a second. Numba caches
them beside the module (``cmrt/control/__pycache__``; a user's virtual environment can write there) or, where it
cannot write, in its user-wide cache (``NUMBA_CACHE_DIR`` chooses another).
"""

from __future__ import annotations

import os
import sys
from typing import TextIO

from cmrt.control import kernel

_noted: set[str] = set()


def kernels_cached(dispatcher=None) -> bool | None:
    """Whether numba's cache holds a body's main kernel (default the planar ``kernel.control_step``) compiled for
    this machine; None if numba does not say (its cache's layout is not public API)."""
    try:
        return os.path.exists((dispatcher or kernel.control_step)._cache._cache_file._index_path)
    except Exception:  # noqa: BLE001 - another numba: no note rather than a wrong one
        return None


def note_first_compile(stream: TextIO | None = None, dispatcher=None) -> bool:
    """Say once per process and kernel, before the first clip, that a body's kernels (default the planar body's)
    are being compiled when numba's cache does not have them. Returns whether it said so."""
    name = getattr(dispatcher or kernel.control_step, "__name__", "kernel")
    if name in _noted:
        return False
    _noted.add(name)
    if kernels_cached(dispatcher) is not False:
        return False
    print("cmrt: compiling the controller's kernels for this machine, once (under a minute on a 2-core VM; later "
          "runs load them from numba's cache)", file=sys.stderr if stream is None else stream, flush=True)
    return True
