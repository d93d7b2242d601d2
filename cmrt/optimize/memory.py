"""How much memory a batch of simulations takes, and how many clips one batch may hold.

A simulated clip keeps its per-step record (CoM, CoP, contacts, tracking, state: what the objective and the
success checks read) until it is scored, so a batch's memory grows with clips x steps. Measured with
``python tools/bench_memory.py`` (peak RSS of a fresh process scoring one batch; docs/service.md):

* about 0.67 kB per clip per 2 ms physics step (bend, 2.6 s clip: 1.16-1.23 MB a clip; 59.5 s: 19.4 MB);
* plus a fixed part per clip (its MuJoCo data, controller rows) of about 0.19 MB.

:func:`clip_bytes` is that model with a margin (0.7 kB a step, 256 kB a clip). A generation is simulated
in batches of at most :func:`clips_per_batch` clips, so that no batch needs more than
``$CMRT_MEMORY_SHARE`` (default 0.25) of the machine's RAM whatever the population, the IPOP growth or the
robust ensemble: a ``--robust --popsize 100`` run on a 59.5 s clip (700 clips, 14.9 GB by the model) runs
in batches of 43 candidates (301 clips) on a 24 GB machine. Results do not depend on the batch size: every
clip is simulated on its own row (``mujoco.batch`` is bit-identical to stepping each clip alone; tested).
"""

from __future__ import annotations

import ctypes
import functools
import math
import os
import platform
from typing import TYPE_CHECKING

from cmrt.inputs import Range

if TYPE_CHECKING:
    from cmrt.motion.task import Task

PHYSICS_TIMESTEP_S = 0.002  # cmrt/body/humanoid.xml <option timestep>
STEP_BYTES = 700  # per clip per physics step (measured 668 B: tools/bench_memory.py)
CLIP_BASE_BYTES = 256 * 1024  # per clip, whatever its length (measured ~190 kB)
DEFAULT_MEMORY_SHARE = 0.25  # of physical RAM, for one batch of clips
MEMORY_SHARE_ENV = "CMRT_MEMORY_SHARE"


M_MMAP_THRESHOLD = -3  # glibc mallopt parameter
MMAP_THRESHOLD_BYTES = 128 * 1024  # glibc's initial default, kept fixed


@functools.cache
def bound_heap_growth() -> bool:
    """Fix glibc's mmap threshold at its 128 kB default (once per process; True if done).

    glibc raises the threshold each time a large mmapped block is freed, so after the first batch a clip's
    per-step arrays come from the heap, and batch after batch the heap fragments: a process scoring 160
    bend clips per batch grew from 480 MB to 737 MB over 12 batches (and a population-1280 run to 3.2 GB,
    against the 2 GB this model gives), with no Python object left alive (tracemalloc). With the threshold
    fixed it stays at 487 MB, at the same speed (tools/bench_memory.py, docs/service.md). Setting it with
    ``mallopt`` also turns glibc's dynamic adjustment off; ``MALLOC_MMAP_THRESHOLD_`` in the environment
    would do the same but only from process start."""
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        return bool(ctypes.CDLL(None).mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))
    except (OSError, AttributeError):
        return False


def clip_bytes(task: Task) -> int:
    """The model's bytes for one simulated clip of ``task`` (clip and standing tail) until it is scored."""
    steps = math.ceil((task.clip_s + task.tail_s) / PHYSICS_TIMESTEP_S)
    return CLIP_BASE_BYTES + STEP_BYTES * steps


def physical_memory_bytes() -> int:
    """This machine's RAM (POSIX sysconf; 8 GB assumed where it cannot be read)."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 8 * 2**30


SHARE = Range(0.0, 1.0, lo_open=True)


def memory_share() -> float:
    """``$CMRT_MEMORY_SHARE``: the share of RAM one batch may use, in (0, 1] (default 0.25)."""
    text = os.environ.get(MEMORY_SHARE_ENV, "").strip()
    return SHARE.check(text, f"${MEMORY_SHARE_ENV}") if text else DEFAULT_MEMORY_SHARE


def clips_per_batch(task: Task) -> int:
    """The most clips of ``task`` one batch may hold under the memory share (at least one)."""
    return max(1, int(memory_share() * physical_memory_bytes()) // clip_bytes(task))
