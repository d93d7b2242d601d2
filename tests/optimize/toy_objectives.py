"""Toy objectives for driver and checkpoint tests: the optimizer's behaviour does not depend on what is
simulated, so these stand in for clips (seconds 0)."""

import numpy as np

from cmrt.optimize.driver import EvalRecord


def sphere(xs):
    """Smooth, every candidate a success: the search converges on (0.3, ..., 0.3)."""
    return [EvalRecord(float(np.sum((x - 0.3) ** 2)), False, 0.0, success=True) for x in xs]


def rugged(xs):
    """Stall-prone: flat steps, a success only in a narrow well far from the start, so the search restarts
    (IPOP) every few generations."""
    out = []
    for x in xs:
        d = float(np.sum((x - 1.5) ** 2))
        out.append(EvalRecord(1.0 + 0.001 * np.floor(d), d > 0.05, 0.0, success=d < 0.05))
    return out
