"""MuJoCo's C functions for compiled loops: the library the ``mujoco`` wheel ships, opened once with ctypes.

numba calls a ctypes function handed to it as an argument (a first-class function: its address travels as a value,
so the compiled loop stays cacheable) on ``MjModel._address`` and ``MjData._address``, the same structs the
binding's calls get. It is the same C function the binding calls, so the physics is the same bit for bit
(tests/sim/test_spatial_loop.py). What is lost is the binding's error translation: a MuJoCo *error* (not a warning)
inside a compiled loop prints MuJoCo's message and ends the process (status 1; seen on a model given a 20 KB
arena). Stepping the 3D body raises none: a toppling clip peaks at 63 KB of its 15.7 MB arena, and a diverging state
is a warning (MuJoCo resets the data). Only ``mj_step`` and ``mj_subtreeVel`` are bound.
"""

from __future__ import annotations

import ctypes
import functools
import glob
import os
from dataclasses import dataclass

import mujoco


@dataclass(frozen=True)
class CFunctions:
    """``mj_step(m, d)`` and ``mj_subtreeVel(m, d)``, each taking the two structs' addresses."""

    step: ctypes._CFuncPtr
    subtree_vel: ctypes._CFuncPtr


@functools.cache
def c_functions() -> CFunctions | None:
    """The C library beside the ``mujoco`` package (Linux's .so, macOS's .dylib, Windows' .dll), already loaded by
    the binding, so one library and one set of globals; None where a build of mujoco keeps it elsewhere (the
    callers then run their Python loops: the same clips, slower)."""
    folder = os.path.dirname(mujoco.__file__)
    found = sorted(name for pattern in ("libmujoco*.so*", "libmujoco*.dylib", "mujoco*.dll")
                   for name in glob.glob(os.path.join(folder, pattern)))
    if not found or not hasattr(mujoco.MjData, "_address"):
        return None
    try:
        lib = ctypes.CDLL(found[0])
    except OSError:
        return None
    functions = []
    for name in ("mj_step", "mj_subtreeVel"):
        fn = getattr(lib, name)
        fn.argtypes, fn.restype = [ctypes.c_void_p, ctypes.c_void_p], None
        functions.append(fn)
    return CFunctions(*functions)
