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

A CMRT in two axes (a 3D task's ``cmrt_axes = 2``, docs/body3d.md) adds ``cross_values_m``: a second
displacement across the task's own axis (a pose change's sideways, +y to the left; a leg lift's forward, +x) at
the same knot times, a clamped spline through (0, 0), its knots and (L, 0) as the first. Its parameters are the 12
``u[0:8]`` as above and ``u[8:12]`` the cross values in units of ``VALUE_SCALE_M``. Shared knot times, measured:
on the 3D punch separate ones (16 parameters) found no better CMRT and found it later (docs/body3d.md).
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
N_PARAMS = 2 * N_KNOTS  # a one-axis CMRT's optimizer parameters
N_PARAMS_TWO_AXES = 3 * N_KNOTS  # ... and a two-axis one's (shared knot times)
VALUE_SCALE_M = 0.05
MIN_GAP_S = 0.05
#: A CMRT given by a user (a file, a stored run): its clip and its displacements (a metre of CoM shift is
#: already far outside any foot).
CLIP_S = Range(0.0, MAX_RUN_S, lo_open=True, unit="s")
VALUE_M = Range(-1.0, 1.0, unit="m")
CMRT_KEYS = frozenset({"clip_s", "knot_times_s", "values_m"})
CROSS_KEY = "cross_values_m"  # a two-axis CMRT's own key (a one-axis CMRT's dict has none)


def n_params(axes: int) -> int:
    """The optimizer's parameters of a CMRT in ``axes`` (1 or 2) horizontal axes."""
    return N_PARAMS if axes == 1 else N_PARAMS_TWO_AXES


@dataclass(frozen=True)
class Cmrt:
    """A CMRT over a clip of ``clip_s`` seconds; knots in seconds, values in metres."""

    clip_s: float
    knot_times_s: tuple[float, ...]
    values_m: tuple[float, ...]
    cross_values_m: tuple[float, ...] | None = None  # across the task's axis, at the same knots; None: one axis

    def __post_init__(self) -> None:
        t = np.asarray(self.knot_times_s, dtype=float)
        v = np.asarray(self.values_m, dtype=float)
        cross = np.asarray(self.cross_values_m if self.cross_values_m is not None else self.values_m, dtype=float)
        if t.shape != (N_KNOTS,) or v.shape != (N_KNOTS,) or cross.shape != (N_KNOTS,):
            raise CmrtError(f"a CMRT has {N_KNOTS} knot times and {N_KNOTS} values (per axis)")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v)) and np.all(np.isfinite(cross))):
            raise CmrtError("CMRT knots and values must be finite")
        if not (0.0 < t[0] and np.all(np.diff(t) > 0) and t[-1] < self.clip_s):
            raise CmrtError(f"CMRT knot times must be increasing inside (0, {self.clip_s}) s")

    @property
    def axes(self) -> int:
        """1, or 2 for a CMRT with ``cross_values_m``."""
        return 1 if self.cross_values_m is None else 2

    @classmethod
    def zero(cls, clip_s: float, axes: int = 1) -> Cmrt:
        """The flat CMRT with equally spaced knots: no anticipation (in ``axes`` axes)."""
        return cls.from_params(np.zeros(n_params(axes)), clip_s)

    @classmethod
    def from_params(cls, u: np.ndarray, clip_s: float) -> Cmrt:
        """The CMRT of CMA-ES's vector ``u``: 4 knot values in units of VALUE_SCALE_M, then 4 knot-gap logits
        (8 numbers); a two-axis CMRT's 4 cross values after them (12)."""
        u = np.asarray(u, dtype=float)
        if u.shape not in ((N_PARAMS,), (N_PARAMS_TWO_AXES,)):
            raise CmrtError(f"expected {N_PARAMS} CMRT parameters ({N_PARAMS_TWO_AXES} in two axes), got shape "
                            f"{u.shape}")
        logits = np.concatenate([[0.0], u[N_KNOTS:N_PARAMS]])
        w = np.exp(logits - logits.max())
        gaps = MIN_GAP_S + (clip_s - (N_KNOTS + 1) * MIN_GAP_S) * w / w.sum()
        times = np.cumsum(gaps)[:N_KNOTS]
        cross = tuple(map(float, u[N_PARAMS:] * VALUE_SCALE_M)) if u.size > N_PARAMS else None
        return cls(float(clip_s), tuple(map(float, times)), tuple(map(float, u[:N_KNOTS] * VALUE_SCALE_M)), cross)

    def to_params(self) -> np.ndarray:
        """Inverse of :meth:`from_params` (exact up to rounding)."""
        t = np.concatenate([[0.0], self.knot_times_s, [self.clip_s]])
        excess = np.diff(t) - MIN_GAP_S
        if np.any(excess <= 0):
            raise CmrtError(f"knot gaps must exceed {MIN_GAP_S} s to map to parameters")
        logits = np.log(excess[1:] / excess[0])
        cross = [] if self.cross_values_m is None else np.asarray(self.cross_values_m) / VALUE_SCALE_M
        return np.concatenate([np.asarray(self.values_m) / VALUE_SCALE_M, logits, cross])

    def _clamped(self, values: tuple[float, ...]) -> CubicSpline:
        x = np.concatenate([[0.0], self.knot_times_s, [self.clip_s]])
        y = np.concatenate([[0.0], values, [0.0]])
        return CubicSpline(x, y, bc_type="clamped")

    @functools.cached_property
    def _spline(self) -> CubicSpline:
        return self._clamped(self.values_m)

    @functools.cached_property
    def cross(self) -> Cmrt:
        """The displacement across the task's axis as a one-axis CMRT of its own (the zero CMRT's values, at these
        knots, for a one-axis CMRT): what a 3D clip plays in that axis."""
        values = self.cross_values_m if self.cross_values_m is not None else (0.0,) * N_KNOTS
        return Cmrt(self.clip_s, self.knot_times_s, values)

    def along(self) -> Cmrt:
        """The displacement along the task's axis alone (this CMRT without its cross values)."""
        return self if self.cross_values_m is None else Cmrt(self.clip_s, self.knot_times_s, self.values_m)

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
        """JSON-ready form (``from_dict`` round-trips it); ``cross_values_m`` only in two axes."""
        out = {"clip_s": self.clip_s, "knot_times_s": list(self.knot_times_s), "values_m": list(self.values_m)}
        if self.cross_values_m is not None:
            out[CROSS_KEY] = list(self.cross_values_m)
        return out

    @classmethod
    def from_dict(cls, obj: dict, where: str = "CMRT", values: Range = Range()) -> Cmrt:
        """From ``to_dict``'s form, checked: exactly ``clip_s`` (in (0, 60] s), ``knot_times_s`` and
        ``values_m`` (4 finite numbers each, values inside ``values``: a user's file is held to ``VALUE_M``,
        +-1 m), and in two axes ``cross_values_m`` as ``values_m``; CmrtError naming ``where`` otherwise."""
        if not isinstance(obj, dict) or set(obj) - {CROSS_KEY} != CMRT_KEYS:
            got = sorted(map(str, obj)) if isinstance(obj, dict) else obj
            raise CmrtError(f"{where}: not a CMRT object (need exactly clip_s, knot_times_s, values_m, and "
                            f"{CROSS_KEY} in two axes), got {shown(got)}")
        clip_s = inputs.number(obj["clip_s"], f"{where}: clip_s", CLIP_S, text=False)
        lists = {}
        keys = (("knot_times_s", Range()), ("values_m", values)) + (((CROSS_KEY, values),) if CROSS_KEY in obj else ())
        for key, allowed in keys:
            value = obj[key]
            if not isinstance(value, list) or len(value) != N_KNOTS:
                raise CmrtError(f"{where}: {key} must be a list of {N_KNOTS} numbers, got {shown(value)}")
            lists[key] = tuple(inputs.number(v, f"{where}: {key}", allowed, text=False) for v in value)
        try:
            return cls(clip_s, lists["knot_times_s"], lists["values_m"], lists.get(CROSS_KEY))
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
