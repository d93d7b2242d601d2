"""Momentum balance control (Macchietto et al. 2009, restated in ABC section 3).

The names below load on first use (PEP 562): a module that only needs the reference modes
(``cmrt.control.references``) does not pay for compiling the controller's kernel (numba).
"""

from __future__ import annotations

import importlib

_API = {
    "ControllerConfig": "cmrt.control.controller",
    "MomentumBalanceController": "cmrt.control.controller",
    "centroidal_momentum_matrix": "cmrt.control.momentum",
}
__all__ = sorted(_API)


def __getattr__(name: str):
    if name not in _API:
        raise AttributeError(f"module 'cmrt.control' has no attribute {name!r}")
    return getattr(importlib.import_module(_API[name]), name)
