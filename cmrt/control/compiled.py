"""Whether the controller's compiled kernels (numba, ``cmrt.control.kernel``) are in numba's cache, and a one-line
note on stderr when they are not: the first clip after an install compiles them for this machine (about 30 s on the
project's 2-core VM, measured by ``tools/first_run.py``), every later one loads them in about a second. Numba
caches them beside the module (``cmrt/control/__pycache__``; a user's virtual environment can write there) or, where
it cannot write, in its user-wide cache (``NUMBA_CACHE_DIR`` chooses another).
"""

from __future__ import annotations

import os
import sys
from typing import TextIO

from cmrt.control import kernel

_noted = False


def kernels_cached() -> bool | None:
    """Whether numba's cache holds the controller's main kernel (``kernel.control_step``) compiled for this
    machine; None if numba does not say (its cache's layout is not public API)."""
    try:
        return os.path.exists(kernel.control_step._cache._cache_file._index_path)
    except Exception:  # noqa: BLE001 - another numba: no note rather than a wrong one
        return None


def note_first_compile(stream: TextIO | None = None) -> bool:
    """Say once per process, before the first clip, that the kernels are being compiled when numba's cache does
    not have them. Returns whether it said so."""
    global _noted
    if _noted:
        return False
    _noted = True
    if kernels_cached() is not False:
        return False
    print("cmrt: compiling the controller's kernels for this machine, once (about 30 s on a 2-core VM; later runs "
          "load them from numba's cache)", file=sys.stderr if stream is None else stream, flush=True)
    return True
