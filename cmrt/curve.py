"""The CMRT: a clamped cubic spline of horizontal CoM displacement (ABC section 4).

d(t) passes through (0, 0), four control points (t_i, v_i) and (L, 0), with zero
slope at both ends, so a CMRT never kicks the CoM at the start or end of a clip.

CMA-ES works on an unconstrained 8-vector ``u`` that maps to valid knots:

* ``u[0:4]`` are the control values in units of ``VALUE_SCALE_M`` (5 cm), so a unit
  step of the search moves the CoM target by a plausible amount;
* ``u[4:8]`` are log-ratios of the five gaps between 0, t_1..t_4 and L: gap_k =
  MIN_GAP_S + (L - 5 MIN_GAP_S) * softmax([0, u4, u5, u6, u7])_k. Every u gives
  strictly ordered knots at least ``MIN_GAP_S`` apart inside (0, L); u = 0 is the
  flat spline with equally spaced knots (ABC's initial guess).
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

from cmrt.errors import CmrtError

N_KNOTS = 4
VALUE_SCALE_M = 0.05
MIN_GAP_S = 0.05


@dataclass(frozen=True)
class Cmrt:
    """A CMRT over a clip of ``clip_s`` seconds; knots in seconds, values in metres."""

    clip_s: float
    knot_times_s: tuple[float, ...]
    values_m: tuple[float, ...]

    def __post_init__(self) -> None:
        t = np.asarray(self.knot_times_s, dtype=float)
        v = np.asarray(self.values_m, dtype=float)
        if t.shape != (N_KNOTS,) or v.shape != (N_KNOTS,):
            raise CmrtError(f"a CMRT has {N_KNOTS} knot times and {N_KNOTS} values")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
            raise CmrtError("CMRT knots and values must be finite")
        if not (0.0 < t[0] and np.all(np.diff(t) > 0) and t[-1] < self.clip_s):
            raise CmrtError(f"CMRT knot times must be increasing inside (0, {self.clip_s}) s")

    @classmethod
    def zero(cls, clip_s: float) -> Cmrt:
        """The flat CMRT with equally spaced knots: no anticipation."""
        return cls.from_params(np.zeros(2 * N_KNOTS), clip_s)

    @classmethod
    def from_params(cls, u: np.ndarray, clip_s: float) -> Cmrt:
        """The CMRT of CMA-ES's 8-vector ``u``: 4 knot values in units of VALUE_SCALE_M, then 4 knot-gap logits."""
        u = np.asarray(u, dtype=float)
        if u.shape != (2 * N_KNOTS,):
            raise CmrtError(f"expected {2 * N_KNOTS} CMRT parameters, got shape {u.shape}")
        logits = np.concatenate([[0.0], u[N_KNOTS:]])
        w = np.exp(logits - logits.max())
        gaps = MIN_GAP_S + (clip_s - (N_KNOTS + 1) * MIN_GAP_S) * w / w.sum()
        times = np.cumsum(gaps)[:N_KNOTS]
        return cls(float(clip_s), tuple(map(float, times)), tuple(map(float, u[:N_KNOTS] * VALUE_SCALE_M)))

    def to_params(self) -> np.ndarray:
        """Inverse of :meth:`from_params` (exact up to rounding)."""
        t = np.concatenate([[0.0], self.knot_times_s, [self.clip_s]])
        excess = np.diff(t) - MIN_GAP_S
        if np.any(excess <= 0):
            raise CmrtError(f"knot gaps must exceed {MIN_GAP_S} s to map to parameters")
        logits = np.log(excess[1:] / excess[0])
        return np.concatenate([np.asarray(self.values_m) / VALUE_SCALE_M, logits])

    @functools.cached_property
    def _spline(self) -> CubicSpline:
        x = np.concatenate([[0.0], self.knot_times_s, [self.clip_s]])
        y = np.concatenate([[0.0], self.values_m, [0.0]])
        return CubicSpline(x, y, bc_type="clamped")

    def displacement_m(self, t_s: np.ndarray | float) -> np.ndarray:
        """d(t); zero outside [0, L]."""
        t = np.asarray(t_s, dtype=float)
        inside = (t >= 0.0) & (t <= self.clip_s)
        return np.where(inside, self._spline(np.clip(t, 0.0, self.clip_s)), 0.0)

    def velocity_m_s(self, t_s: np.ndarray | float) -> np.ndarray:
        """d'(t); zero outside [0, L]."""
        t = np.asarray(t_s, dtype=float)
        inside = (t >= 0.0) & (t <= self.clip_s)
        return np.where(inside, self._spline(np.clip(t, 0.0, self.clip_s), 1), 0.0)

    def to_dict(self) -> dict:
        """JSON-ready form (``from_dict`` round-trips it)."""
        return {"clip_s": self.clip_s, "knot_times_s": list(self.knot_times_s), "values_m": list(self.values_m)}

    @classmethod
    def from_dict(cls, obj: dict) -> Cmrt:
        """From ``to_dict``'s form; CmrtError if it is not one."""
        try:
            return cls(float(obj["clip_s"]), tuple(map(float, obj["knot_times_s"])), tuple(map(float, obj["values_m"])))
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, CmrtError):
                raise
            raise CmrtError(f"not a CMRT object (need clip_s, knot_times_s, values_m): {exc}") from None

    def to_json(self) -> str:
        """``to_dict`` as JSON text."""
        return json.dumps(self.to_dict())

    @classmethod
    def from_json(cls, text: str) -> Cmrt:
        """From JSON text (a CMRT file's content)."""
        try:
            obj = json.loads(text)
        except json.JSONDecodeError as exc:
            raise CmrtError(f"CMRT file is not JSON: {exc}") from None
        if isinstance(obj, dict) and "cmrt" in obj:
            obj = obj["cmrt"]
        if not isinstance(obj, dict):
            raise CmrtError("CMRT JSON must be an object")
        return cls.from_dict(obj)

    @classmethod
    def load(cls, path: str | Path) -> Cmrt:
        """A CMRT from a JSON file (as ``cmrt interpolate --out`` writes)."""
        try:
            text = Path(path).read_text()
        except OSError as exc:
            raise CmrtError(f"cannot read CMRT file {path}: {exc.strerror}") from None
        return cls.from_json(text)
