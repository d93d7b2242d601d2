"""The optimizer's and the job queue's defaults, written once: the API's signatures, the job queue and the
CLI's ``--help`` read them here. Constants and a frozen record only, so that building the CLI's parser
loads no pycma, numba or MuJoCo."""

from __future__ import annotations

from dataclasses import dataclass

from cmrt.errors import CmrtError

FAMILY_SIGMA0 = 0.15  # step size of a speed family's warm-started members (parameter units)
STALE_AFTER_S = 120.0  # a running job whose heartbeat is older than this is an orphan a worker resumes

STALL_RULES = ("hybrid", "median", "best")


@dataclass(frozen=True)
class OptimizeSettings:
    """The optimizer's settings; the defaults here are the only place they are written (CLI, jobs read them)."""

    seed: int = 1
    max_evals: int = 3000
    min_evals: int = 700  # slow-convergence tests only after this many evaluations (ABC 4.1)
    popsize: int = 10
    sigma0: float = 0.5  # in parameter units: 2.5 cm of CoM shift, knot-gap log-ratio 0.5
    stop_threshold: float = 0.0
    stall_generations: int = 20
    stall_tol: float = 1e-3
    x0: tuple[float, ...] | None = None  # warm start (parameters of a stored result)
    max_restarts: int = 30  # restarts of a stalled search (large and small regimes together)
    popsize_factor: float = 2.0  # each large restart multiplies the population by this
    bipop: bool = True  # alternate large and small restarts (BIPOP); False: large only (IPOP)
    # "hybrid": the median test (below) only until the run's first success, the best alone after it;
    # "median": the median test throughout (v0.4); "best": the best alone throughout (v0.3)
    stall_rule: str = "hybrid"
    n_params: int = 8  # the CMRT's parameters (``Task.n_cmrt_params``): 8, or 12 for a CMRT in x and y

    def __post_init__(self) -> None:
        if self.stall_rule not in STALL_RULES:
            raise CmrtError(f"stall_rule must be one of {', '.join(STALL_RULES)}, got {self.stall_rule!r}"[:200])
        if self.n_params not in (8, 12):
            raise CmrtError(f"n_params must be 8 or 12 (a CMRT in one axis or two), got {self.n_params!r}"[:200])
        if self.x0 is not None and len(self.x0) != self.n_params:
            raise CmrtError(f"a start point of {len(self.x0)} parameters for a CMRT of {self.n_params}")
