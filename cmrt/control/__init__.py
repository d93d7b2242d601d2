"""Momentum balance control (Macchietto et al. 2009, restated in ABC section 3)."""

from cmrt.control.controller import ControllerConfig, MomentumBalanceController
from cmrt.control.momentum import centroidal_momentum_matrix

__all__ = ["ControllerConfig", "MomentumBalanceController", "centroidal_momentum_matrix"]
