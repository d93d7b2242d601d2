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

from cmrt import inputs
from cmrt.errors import CmrtError
from cmrt.inputs import MAX_RUN_S, Range, shown

N_KNOTS = 4
VALUE_SCALE_M = 0.05
MIN_GAP_S = 0.05
#: A CMRT given by a user (a file, a stored run): its clip and its displacements (a metre of CoM shift is
#: already far outside any foot).
CLIP_S = Range(0.0, MAX_RUN_S, lo_open=True, unit="s")
VALUE_M = Range(-1.0, 1.0, unit="m")
CMRT_KEYS = frozenset({"clip_s", "knot_times_s", "values_m"})


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
    def from_dict(cls, obj: dict, where: str = "CMRT", values: Range = Range()) -> Cmrt:
        """From ``to_dict``'s form, checked: exactly ``clip_s`` (in (0, 60] s), ``knot_times_s`` and
        ``values_m`` (4 finite numbers each, values inside ``values``: a user's file is held to ``VALUE_M``,
        +-1 m); CmrtError naming ``where`` otherwise."""
        if not isinstance(obj, dict) or set(obj) != CMRT_KEYS:
            got = sorted(map(str, obj)) if isinstance(obj, dict) else obj
            raise CmrtError(f"{where}: not a CMRT object (need exactly clip_s, knot_times_s, values_m), got "
                            f"{shown(got)}")
        clip_s = inputs.number(obj["clip_s"], f"{where}: clip_s", CLIP_S, text=False)
        lists = {}
        for key, allowed in (("knot_times_s", Range()), ("values_m", values)):
            value = obj[key]
            if not isinstance(value, list) or len(value) != N_KNOTS:
                raise CmrtError(f"{where}: {key} must be a list of {N_KNOTS} numbers, got {shown(value)}")
            lists[key] = tuple(inputs.number(v, f"{where}: {key}", allowed, text=False) for v in value)
        try:
            return cls(clip_s, lists["knot_times_s"], lists["values_m"])
        except CmrtError as exc:
            raise CmrtError(f"{where}: {exc}") from None

    def to_json(self) -> str:
        """``to_dict`` as JSON text."""
        return json.dumps(self.to_dict())

    @classmethod
    def from_json(cls, text: str, where: str = "CMRT file") -> Cmrt:
        """From JSON text (a CMRT file's content: a CMRT object, or an object with one under ``cmrt`` as
        ``cmrt interpolate --json`` prints)."""
        obj = inputs.parse_json(text, where)
        if isinstance(obj, dict) and "cmrt" in obj:
            obj = obj["cmrt"]
        if not isinstance(obj, dict):
            raise CmrtError(f"{where}: CMRT JSON must be an object, got {shown(obj)}")
        return cls.from_dict(obj, where, VALUE_M)

    @classmethod
    def load(cls, path: str | Path) -> Cmrt:
        """A CMRT from a JSON file (as ``cmrt interpolate --out`` writes): a regular UTF-8 file of at most
        ``cmrt.inputs.MAX_FILE_BYTES``."""
        return cls.from_json(inputs.read_text(path, "CMRT file"), f"CMRT file {shown(str(path))}")
