"""Can a task's keyed motion be done on time with both feet flat? Checked before it is simulated.

The driving joints (every actuated joint but the ankles, the task's balance joint) follow the reference exactly;
the ankles are free: ankle(t) = keyed ankle(t) + delta(t), which turns the body about the ankle axis and moves
the CoM horizontally - what the controller does to balance, and what a CMRT shifts ahead of time. For a given
delta, ``cmrt.motion.loads`` gives exact inverse dynamics at every 5 ms sample. Each sample must have:

* the CoP inside the feet [heel, toe] (every heel and toe point pushing, by the controller's lever rule),
* every motor within its torque limit (the MJCF's, as the controller uses),
* |F_x| <= mu F_z with mu the floor's friction (``floor_friction``),
* F_z >= 0.25 body weight (``MIN_VERTICAL_FORCE_BW``).

delta is a cubic B-spline (knots every ``KNOT_S``), zero with zero rate before the search's start and at the
clip's end, as a CMRT is. Sequential linear programming (HiGHS) minimises the largest normalised violation: the
constraints are linearised in delta's coefficients by finite differences of the exact inverse dynamics (each
sample's loads depend on delta, its rate and its acceleration there alone), a trust region bounds each step,
and every step is re-evaluated exactly. Three searches, the physical case for anticipation:

* ``any``: delta free over the whole clip (a CMRT can shift the CoM before the motion starts);
* ``from_onset``: delta zero until the motion's onset P (a controller that acts only once the motion starts);
* ``from_reaction``: delta zero until P + 0.1 s (one that reacts after the controller's feedback delay).

A verdict (docs/feasibility.md): feasible if the best delta of ``any`` meets every constraint; it needs
anticipation if it is feasible but not from the reaction on.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.optimize import linprog

from cmrt.body.character import character
from cmrt.control.controller import ControllerConfig
from cmrt.errors import CmrtError
from cmrt.inputs import shown
from cmrt.motion.loads import DT_S, FlatFootMotion, Loads, body_weight_n, keyed_motion, loads
from cmrt.motion.task import Task

#: The least vertical ground force (body weights) a feasible motion keeps. Below ~0.23 BW the controller cannot
#: keep its contact-force floor of 40 N on each of the four heel/toe points (160 N = 0.23 BW), and the CoP of so
#: small a load is meaningless: a soft contact's sinking, not the feet, decides where it is.
MIN_VERTICAL_FORCE_BW = 0.25
KNOT_S = 0.025  # delta's B-spline knot spacing (s): it can turn within ~0.1 s; 0.1 s (the reaction) is 4 of them
MAX_ITERATIONS = 40
TOLERANCE = 1e-3  # stop when a step would lower the merit by less (0.24 mm of CoP, 0.1 % of a torque limit)
#: A normalised violation this small is within the check's precision (the search's tolerance), not a violation: 0.24 mm
#: of CoP, 0.1 % of a torque limit or of the floor's friction, 0.001 body weight.
PRECISION = TOLERANCE
SPREAD_PER_S = 1.0  # weight (1/s) of the violations' integral over the clip beside the worst (the any search)
SHIFT_WEIGHT = 1e-3  # and of the coefficients' mean size (rad): it only tells paths as good apart (3 cm: 3e-5)
NEAR_WORST = 0.05  # the linear programs take the rows this close to the worst or to their bound, and the last ones
MAX_ROUNDS = 20
FD_STEP = 1e-6  # finite-difference step in delta (rad), its rate (rad/s) and its acceleration (rad/s^2)
START_RADIUS_RAD = 0.02  # first trust region: each B-spline coefficient moves at most this (~2 cm of CoM)
MAX_RADIUS_RAD = 0.16
TRUST_TIME_S = 0.1  # and its acceleration at most radius / TRUST_TIME_S^2 (the coefficients' second differences)
MIN_RADIUS_RAD = 1e-5
SEARCHES = ("any", "from_onset", "from_reaction")


@dataclass(frozen=True)
class LoadSummary:
    """What a motion asks for, at its worst: the verdict's figures for one ankle path."""

    min_vertical_force_bw: float
    min_vertical_force_t_s: float
    friction_needed: float  # max |F_x| / F_z where the feet carry >= 0.25 BW (below, the ratio means nothing)
    min_cop_margin_m: float  # smallest distance of the CoP inside the feet (< 0: outside), where F_z >= 0.25 BW
    peak_torque_nm: dict[str, float]  # per actuator, max |tau|

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass(frozen=True)
class Search:
    """One search over the ankle shift: where it may start, and the best it found."""

    name: str  # any, from_onset, from_reaction
    free_from_s: float  # delta is zero before this
    worst_violation: float  # the largest normalised violation (<= 0: feasible; the constraint's own units / scale)
    worst: str  # which constraint that is
    com_shift_range_m: tuple[float, float]  # the CoM's horizontal shift from the keyed motion's
    ankle_shift_range_deg: tuple[float, float]
    iterations: int

    @property
    def feasible(self) -> bool:
        return self.worst_violation <= PRECISION

    def to_dict(self) -> dict:
        return {**self.__dict__, "feasible": self.feasible}


@dataclass(frozen=True)
class Feasibility:
    """``check_reference``'s answer for one task (``to_dict``: what ``cmrt check --json`` prints)."""

    task: str
    speed: float | None
    feasible: bool  # the best ankle path of ``any`` meets every constraint at every sample (within PRECISION)
    needs_anticipation: bool  # feasible, but not with a path that starts 0.1 s after the onset
    from_onset_suffices: bool  # a path that starts at the onset meets every constraint
    first_violation: str | None  # the first constraint the best path breaks, as a sentence (None: feasible)
    keyed: LoadSummary  # the keyed ankle, literally
    best: LoadSummary  # the best ankle shift of the ``any`` search
    searches: tuple[Search, ...]
    torque_limit_nm: dict[str, float]
    floor_friction: float
    ignored: tuple[str, ...] = ()  # what the check leaves out (a prop's forces, pushes)
    wall_s: float = field(default=0.0, compare=False)

    def search(self, name: str) -> Search:
        return next(s for s in self.searches if s.name == name)

    def to_dict(self) -> dict:
        return {"task": self.task, "speed": self.speed, "feasible": self.feasible,
                "needs_anticipation": self.needs_anticipation, "from_onset_suffices": self.from_onset_suffices,
                "first_violation": self.first_violation, "min_vertical_force_bw": self.best.min_vertical_force_bw,
                "friction_needed": self.best.friction_needed, "min_cop_margin_m": self.best.min_cop_margin_m,
                "peak_torque_nm": self.best.peak_torque_nm, "torque_limit_nm": self.torque_limit_nm,
                "floor_friction": self.floor_friction, "min_vertical_force_needed_bw": MIN_VERTICAL_FORCE_BW,
                "keyed": self.keyed.to_dict(), "best": self.best.to_dict(),
                "searches": {s.name: s.to_dict() for s in self.searches}, "ignored": list(self.ignored),
                "wall_s": self.wall_s}


def not_checkable(task: Task) -> str | None:
    """Why ``check_reference`` does not apply to ``task`` (None: it does): it checks pose changes with both feet
    planted on a still level floor, balanced by the ankles."""
    if task.gait is not None:
        return "a keyed walking gait"
    if task.steps:
        return "a footstep plan"
    if task.stepping:
        return "a stepping task"
    if task.end_pose_deg is None:
        return "not a pose change (no end pose)"
    if task.balance_joint != "ankle":
        return f"balanced by {shown(task.balance_joint or 'no joint')}, not the ankles"
    if not task.support.still_and_level:
        return "not on a still level floor"
    return None


def check_reference(task: Task) -> Feasibility:
    """Whether ``task``'s keyed motion can be done on time with both feet flat (module docstring); CmrtError if
    the check does not apply to it (``not_checkable``)."""
    why = not_checkable(task)
    if why is not None:
        raise CmrtError(f"cannot check task {shown(task.name)}: {why}; the check is for pose changes with both "
                        "feet planted on a still level floor")
    start = time.perf_counter()
    motion = keyed_motion(task)
    limits = Limits.of(task)
    keyed = loads(motion)
    found = _searches(motion, keyed, limits, task.preparation_s)
    best = found["any"][1]
    searches = tuple(s for s, _ in found.values())
    ok = {name: s.feasible for name, (s, _) in found.items()}
    ch = character()
    names = [ch.dof_names[i] for i in ch.actuated_dofs]
    return Feasibility(
        task=task.name, speed=task.speed, feasible=ok["any"], needs_anticipation=ok["any"] and not ok["from_reaction"],
        from_onset_suffices=ok["from_onset"], first_violation=first_violation(best, limits),
        keyed=summary(keyed, limits), best=summary(best, limits), searches=searches,
        torque_limit_nm=dict(zip(names, map(float, limits.torque_nm), strict=True)),
        floor_friction=limits.friction, ignored=_ignored(task), wall_s=time.perf_counter() - start)


def _ignored(task: Task) -> tuple[str, ...]:
    out = []
    if task.prop:
        out.append(f"the {task.prop}'s forces on the body (the motion is checked alone)")
    if task.push_force_n or any(task.params.get(f"{p}_force_n", 0.0) for p in ("push2", "push3")):
        out.append("the pushes on the thorax")
    return tuple(out)


# --- constraints -------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Limits:
    """The constraints' bounds."""

    torque_nm: np.ndarray  # per actuator
    friction: float  # the floor's
    weight_n: float

    @classmethod
    def of(cls, task: Task) -> Limits:
        return cls(torque_nm=character().torque_limit_nm.astype(float),
                   friction=float(task.params.get("floor_friction", 1.0)), weight_n=body_weight_n())

    @property
    def min_force_n(self) -> float:
        return MIN_VERTICAL_FORCE_BW * self.weight_n


def outputs(ld: Loads) -> np.ndarray:
    """(n, 3 + nu): per sample F_x, F_z, the heel moment and the torques: all the constraints read."""
    return np.column_stack([ld.force_n, ld.heel_moment_nm, ld.torque_nm])


def violations(y: np.ndarray, foot_m: float, lim: Limits) -> tuple[np.ndarray, np.ndarray]:
    """Normalised violations (n, 5 + 2 nu; > 0 violated) and their gradients in ``y`` (n, rows, 3 + nu): F_z
    below 0.25 BW (in body weights), the CoP beyond the toe and behind the heel (in foot lengths: the heel or the
    toe points would have to pull), friction both ways (in mu F_z) and the torques both ways (in their limits).
    Where F_z < 0.25 BW the CoP's and friction's are scaled by 0.25 BW instead of F_z: the same sign, no
    singularity where the ground would pull."""
    n, ny = y.shape
    fx, fz, mh = y[:, 0], y[:, 1], y[:, 2]
    scale = np.maximum(fz, lim.min_force_n)
    dscale = np.zeros((n, ny))
    dscale[:, 1] = fz > lim.min_force_n
    mu = lim.friction
    num = np.stack([mh / foot_m - fz, -mh / foot_m, fx - mu * fz, -fx - mu * fz], axis=1) / [1, 1, mu, mu]
    dnum = np.zeros((n, 4, ny))
    dnum[:, 0, 1], dnum[:, 0, 2] = -1.0, 1.0 / foot_m
    dnum[:, 1, 2] = -1.0 / foot_m
    dnum[:, 2, 0], dnum[:, 2, 1] = 1.0 / mu, -1.0
    dnum[:, 3, 0], dnum[:, 3, 1] = -1.0 / mu, -1.0
    ground = num / scale[:, None]
    dground = dnum / scale[:, None, None] - (num / scale[:, None] ** 2)[:, :, None] * dscale[:, None, :]
    dforce = np.zeros((n, 1, ny))
    dforce[:, 0, 1] = -1.0 / lim.weight_n
    tau = y[:, 3:] / lim.torque_nm
    nu = tau.shape[1]
    dtau = np.zeros((n, 2 * nu, ny))
    eye = np.eye(nu) / lim.torque_nm
    dtau[:, :nu, 3:], dtau[:, nu:, 3:] = eye, -eye
    rows = np.hstack([((lim.min_force_n - fz) / lim.weight_n)[:, None], ground, tau - 1.0, -tau - 1.0])
    return rows, np.concatenate([dforce, dground, dtau], axis=1)


#: The first rows of ``violations``: F_z, the CoP (toe, heel), friction (+x, -x); then the torques (+, -).
FORCE, TOE, HEEL, FRICTION, TORQUE = 0, 1, 2, 3, 5


# --- the search ----------------------------------------------------------------------
def knots(start_s: float, end_s: float, anchor_s: float, knot_s: float = KNOT_S) -> np.ndarray:
    """The centres of the cubic B-splines of a search: on a grid every ``knot_s`` through ``anchor_s`` (the
    motion's onset: the three searches' splines are then nested), two spacings inside [start, end] so that each
    spline and its first two derivatives are zero outside it."""
    first = np.ceil((start_s + 2 * knot_s - anchor_s) / knot_s - 1e-9)
    last = np.floor((end_s - 2 * knot_s - anchor_s) / knot_s + 1e-9)
    return anchor_s + knot_s * np.arange(first, last + 1)


def basis(t_s: np.ndarray, centres: np.ndarray, knot_s: float = KNOT_S) -> np.ndarray:
    """(3, n, k): the cubic B-splines centred at ``centres`` and their first two derivatives at ``t_s``."""
    u = (t_s[:, None] - centres[None, :]) / knot_s
    a = np.abs(u)
    inner, outer = a < 1.0, (a >= 1.0) & (a < 2.0)
    value = np.where(inner, 2.0 / 3.0 - a**2 + 0.5 * a**3, np.where(outer, (2.0 - a) ** 3 / 6.0, 0.0))
    rate = np.where(inner, -2.0 * u + 1.5 * u * a, np.where(outer, -np.sign(u) * (2.0 - a) ** 2 / 2.0, 0.0))
    acc = np.where(inner, -2.0 + 3.0 * a, np.where(outer, 2.0 - a, 0.0))
    return np.stack([value, rate / knot_s, acc / knot_s**2])


@dataclass(frozen=True, eq=False)
class _Point:
    """One ankle path tried by a search: its coefficients, loads, violations and merit."""

    coef: np.ndarray
    loads: Loads
    rows: np.ndarray  # (n, rows searched) normalised violations (``violations``)
    merit: float

    @property
    def worst(self) -> float:
        return float(self.rows.max())


@dataclass(frozen=True, eq=False)
class _Problem:
    """One search: the motion, the ankle path's B-splines, the rows searched and the merit's weights.

    The merit is the worst violation; then, with ``spread`` > 0, each sample's violation beyond its bound summed
    (times ``spread``: where the worst cannot be helped, the rest of the clip is not made worse for nothing);
    then the mean size of the path's coefficients (``SHIFT_WEIGHT``: of paths as good, the one that shifts least).
    Its minimum is feasible if any path is (and feasible, the merit is the worst violation but for the shift)."""

    motion: FlatFootMotion
    lim: Limits
    b: np.ndarray  # (3, n, k): the B-splines and their two derivatives at the samples
    kept: np.ndarray  # the violation rows searched: a right/left twin of a row is left out
    spread: float

    def point(self, coef: np.ndarray) -> _Point:
        ld = loads(self.motion, tuple(self.b @ coef))
        y = outputs(ld)
        rows = violations(y, self.motion.toe_x_m - self.motion.heel_x_m, self.lim)[0][:, self.kept]
        merit = (rows.max() + self.spread * np.maximum(rows.max(axis=1), 0.0).sum()
                 + SHIFT_WEIGHT * (np.abs(coef).mean() if coef.size else 0.0))
        return _Point(coef, ld, rows, float(merit))

    def gradients(self, pt: _Point) -> np.ndarray:
        """d rows / d coef (n, rows, k): each sample's outputs differentiated in delta, its rate and its
        acceleration there (finite differences of the exact inverse dynamics), times the basis."""
        shift = self.b @ pt.coef
        y = outputs(pt.loads)
        dy = np.empty(y.shape + (3,))
        for i in range(3):
            moved = shift.copy()
            moved[i] += FD_STEP
            dy[..., i] = (outputs(loads(self.motion, tuple(moved))) - y) / FD_STEP
        drows = violations(y, self.motion.toe_x_m - self.motion.heel_x_m, self.lim)[1][:, self.kept]
        return (drows @ dy) @ self.b.transpose(1, 0, 2)  # the basis per sample: (n, 3, k)

    def hard_rows(self, pt: _Point, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """The hard rows (A step <= b) a step within ``radius`` could reach: the ankle inside its range less the
        controller's stop margin."""
        ch = character()
        ankle = ch.ankle_dofs[0]
        margin = ControllerConfig().stop_margin_rad
        lo, hi = ch.model.jnt_range[ch.model.dof_jntid[ankle]] + np.array([margin, -margin])
        angle = self.motion.qpos[:, ankle] + self.b[0] @ pt.coef
        high, low = np.flatnonzero(hi - angle < radius), np.flatnonzero(angle - lo < radius)
        return np.vstack([self.b[0][high], -self.b[0][low]]), np.concatenate([(hi - angle)[high], (angle - lo)[low]])


def _lp_step(pb: _Problem, pt: _Point, grads: np.ndarray, radius: float, rows: np.ndarray
             ) -> tuple[np.ndarray, float, np.ndarray]:
    """The step (|each coefficient| <= radius) minimising the linearised merit under the hard rows; returns (step,
    predicted merit, the rows the program ended with).

    Most rows never matter, so the program starts from ``rows`` (the last program's) and those near the worst (and
    near their bound, with ``spread``), and adds the rows its solution breaks or nearly breaks until it breaks none
    (constraint generation: the optimum with every row). Each row has at most four coefficients (the B-splines over
    its sample): the program is sparse."""
    n, r, k = grads.shape
    v, g = pt.rows.ravel(), grads.reshape(-1, k)
    near = v >= pt.worst - NEAR_WORST
    if pb.spread:
        near |= v > -NEAR_WORST
    rows = np.union1d(rows, np.flatnonzero(near))
    hard = pb.hard_rows(pt, radius)
    for _ in range(MAX_ROUNDS):
        solved = _solve(pb, pt, v, g, rows, r, hard, radius)
        if solved is None:
            return np.zeros(k), pt.merit, rows
        step, worst, bound, merit = solved
        predicted = v + g @ step
        limit = np.minimum(worst, bound[np.arange(v.size) // r]) if pb.spread else worst
        if not np.any(np.delete(predicted > limit + 1e-9, rows)):
            break
        rows = np.union1d(rows, np.flatnonzero(predicted > limit - NEAR_WORST))
    return step, merit, rows


def _solve(pb: _Problem, pt: _Point, v: np.ndarray, g: np.ndarray, rows: np.ndarray, r: int, hard: tuple,
           radius: float) -> tuple[np.ndarray, float, np.ndarray, float] | None:
    """The linear program on ``rows``. Variables: the step (k), the worst w, with ``spread`` a slack e_s >= 0 per
    sample with a row, and u_j >= |coefficient j after the step|. Each row i of sample s: v_i + g_i step <= w (and
    <= e_s), w no more than the worst now; minimise w + spread sum(e) + SHIFT_WEIGHT mean(u). Returns (step, w,
    each sample's e (0 without one), merit), or None if it failed."""
    n, k = pt.rows.shape[0], g.shape[1]
    samples, slot = np.unique(rows // r, return_inverse=True)
    m, nr = (samples.size if pb.spread else 0), rows.size
    coef = sparse.csr_array(g[rows])
    eye = sparse.eye_array(k, format="csr")

    def block(step_part, w_col=None, e_part=None, u_part=None):
        h = step_part.shape[0]
        return sparse.hstack([step_part, sparse.csr_array((h, 1)) if w_col is None else w_col,
                              sparse.csr_array((h, m)) if e_part is None else e_part,
                              sparse.csr_array((h, k)) if u_part is None else u_part])

    bend = sparse.diags_array([np.ones(k - 1), -2.0 * np.ones(k), np.ones(k - 1)], offsets=[-1, 0, 1], format="csr")
    blocks = [block(coef, w_col=sparse.csr_array(-np.ones((nr, 1)))), block(sparse.csr_array(hard[0])),
              block(eye, u_part=-eye), block(-eye, u_part=-eye), block(bend), block(-bend)]
    turn = np.full(k, radius * (KNOT_S / TRUST_TIME_S) ** 2)
    b_ub = [-v[rows], hard[1], -pt.coef, pt.coef, turn, turn]
    if m:
        blocks.append(block(coef, e_part=sparse.csr_array((-np.ones(nr), (np.arange(nr), slot)), shape=(nr, m))))
        b_ub.append(-v[rows])
    cost = np.concatenate([np.zeros(k), [1.0], np.full(m, pb.spread), np.full(k, SHIFT_WEIGHT / k)])
    bounds = [(-radius, radius)] * k + [(None, pt.worst)] + [(0.0, None)] * (m + k)
    res = linprog(cost, A_ub=sparse.vstack(blocks, format="csc"), b_ub=np.concatenate(b_ub), bounds=bounds,
                  method="highs")
    if res.status != 0:
        return None
    bound = np.zeros(n)
    bound[samples[:m]] = res.x[k + 1:k + 1 + m]
    return res.x[:k], float(res.x[k]), bound, float(res.fun)


def _search(pb: _Problem, start: np.ndarray) -> tuple[_Point, int]:
    """The ankle path (from coefficients ``start``) that minimises the merit: sequential linear programs in a trust
    region, each step evaluated exactly; the worst violation never rises (so a search started from another's best
    ends no worse). Returns the best point and the number of programs solved."""
    pt = pb.point(start)
    radius, iterations, grads, rows = START_RADIUS_RAD, 0, None, np.zeros(0, int)
    while start.size and iterations < MAX_ITERATIONS and radius >= MIN_RADIUS_RAD:
        iterations += 1
        if grads is None:
            grads = pb.gradients(pt)
        step, predicted, rows = _lp_step(pb, pt, grads, radius, rows)
        promised = pt.merit - predicted
        if promised < TOLERANCE:
            break
        trial = pb.point(pt.coef + step)
        gained = pt.merit - trial.merit
        if gained > 0.1 * promised and trial.worst <= pt.worst + 1e-9:
            pt, grads = trial, None
            radius = min(2.0 * radius if gained > 0.75 * promised else radius, MAX_RADIUS_RAD)
        else:
            radius *= 0.25
    return pt, iterations


def _searches(motion: FlatFootMotion, keyed: Loads, lim: Limits, onset_s: float) -> dict[str, tuple[Search, Loads]]:
    """The three searches, most restricted first; each starts from the one before (their splines are nested),
    so that more freedom never ends worse. Only ``any``'s best path is reported beyond its worst violation and
    shift, so only it weighs the violations beyond the worst (``SPREAD_PER_S``)."""
    starts = {"from_reaction": onset_s + ControllerConfig().feedback_delay_s, "from_onset": onset_s, "any": 0.0}
    kept = _searched_rows(keyed)
    end = float(motion.t_s[-1])
    out, previous = {}, (np.zeros(0), np.zeros(0))
    for name, start_s in starts.items():
        centres = knots(start_s, end, onset_s)
        coef = np.zeros(centres.size)
        coef[np.searchsorted(centres, previous[0] - 1e-9)] = previous[1]
        pb = _Problem(motion, lim, basis(motion.t_s, centres), kept, SPREAD_PER_S * DT_S if name == "any" else 0.0)
        pt, iterations = _search(pb, coef)
        out[name] = (_found(name, start_s, pb.b[0] @ pt.coef, pt, keyed, kept, iterations), pt.loads)
        previous = (centres, pt.coef)
    return {name: out[name] for name in SEARCHES}


def _searched_rows(keyed: Loads) -> np.ndarray:
    """The violation rows a search needs: all but a left limb's torques where the right one's are the same all
    through the keyed motion (the legs always, the arms of a symmetric motion; an ankle shift turns both alike)."""
    ch = character()
    names = [ch.dof_names[i] for i in ch.actuated_dofs]
    nu = len(names)
    twins = [u for u, n in enumerate(names) if n.endswith("_l")
             and np.array_equal(keyed.torque_nm[:, u], keyed.torque_nm[:, names.index(n[:-2] + "_r")])]
    dropped = {TORQUE + u for u in twins} | {TORQUE + nu + u for u in twins}
    return np.array([r for r in range(TORQUE + 2 * nu) if r not in dropped])


def _found(name: str, start_s: float, delta: np.ndarray, pt: _Point, keyed: Loads, kept: np.ndarray,
           iterations: int) -> Search:
    shift = pt.loads.com_m[:, 0] - keyed.com_m[:, 0]
    what = _row_name(int(kept[np.unravel_index(np.argmax(pt.rows), pt.rows.shape)[1]]))
    return Search(name=name, free_from_s=start_s, worst_violation=pt.worst, worst=what,
                  com_shift_range_m=(float(shift.min()), float(shift.max())),
                  ankle_shift_range_deg=(float(np.degrees(delta.min())), float(np.degrees(delta.max()))),
                  iterations=iterations)


def _row_name(row: int) -> str:
    ch = character()
    if row < TORQUE:
        return ("vertical force", "CoP beyond the toes", "CoP behind the heels", "friction", "friction")[row]
    names = [ch.dof_names[i] for i in ch.actuated_dofs]
    return f"{names[(row - TORQUE) % len(names)]} torque"


# --- the report -----------------------------------------------------------------------
def summary(ld: Loads, lim: Limits) -> LoadSummary:
    """The worst of what ``ld`` asks for."""
    fz = ld.force_n[:, 1]
    loaded = fz >= lim.min_force_n
    cop = ld.cop_x_m[loaded]
    ch = character()
    k = int(np.argmin(fz))
    return LoadSummary(
        min_vertical_force_bw=float(fz[k] / lim.weight_n), min_vertical_force_t_s=float(ld.t_s[k]),
        friction_needed=float(np.max(np.abs(ld.force_n[loaded, 0]) / fz[loaded])) if loaded.any() else float("inf"),
        min_cop_margin_m=float(np.min(np.minimum(cop - ld.heel_x_m, ld.toe_x_m - cop))) if loaded.any()
        else float("-inf"),
        peak_torque_nm={ch.dof_names[d]: float(v) for d, v in zip(ch.actuated_dofs, np.abs(ld.torque_nm).max(axis=0),
                                                                   strict=True)})


def first_violation(ld: Loads, lim: Limits) -> str | None:
    """The first constraint ``ld`` violates in time (beyond ``PRECISION``), as a sentence: what, how much at its
    worst in that stretch, when, and the bound (None: none is). At the same instant the vertical force comes first,
    then the CoP, friction and the torques."""
    rows = violations(outputs(ld), ld.toe_x_m - ld.heel_x_m, lim)[0] > PRECISION
    checks = [("force", rows[:, FORCE]), ("toe", rows[:, TOE]), ("heel", rows[:, HEEL]),
              ("friction", rows[:, FRICTION] | rows[:, FRICTION + 1])]
    over = np.abs(ld.torque_nm) > lim.torque_nm * (1.0 + PRECISION)
    checks += [(u, over[:, u]) for u in range(over.shape[1])]
    firsts = [(int(np.argmax(bad)), i) for i, (_, bad) in enumerate(checks) if bad.any()]
    if not firsts:
        return None
    k, i = min(firsts)
    what, bad = checks[i]
    stretch = np.arange(k, k + int(np.argmin(bad[k:])) if not bad[k:].all() else ld.t_s.size)
    return _sentence(ld, lim, what, stretch, over[k])


def _sentence(ld: Loads, lim: Limits, what: str | int, stretch: np.ndarray, over_now: np.ndarray) -> str:
    fz = ld.force_n[stretch, 1]
    if what == "force":
        j = stretch[np.argmin(fz)]
        kind = "the ground must pull: vertical force" if fz.min() < 0 else "the feet carry only"
        return (f"{kind} {ld.force_n[j, 1] / lim.weight_n:.2f} body weights at t = {ld.t_s[j]:.3f} s "
                f"(at least {MIN_VERTICAL_FORCE_BW:g} needed)")
    if what in ("toe", "heel"):
        beyond = (ld.cop_x_m[stretch] - ld.toe_x_m) if what == "toe" else (ld.heel_x_m - ld.cop_x_m[stretch])
        j = stretch[np.nanargmax(beyond)]
        where = "beyond the toes" if what == "toe" else "behind the heels"
        return f"the CoP must be {100 * np.nanmax(beyond):.1f} cm {where} at t = {ld.t_s[j]:.3f} s"
    if what == "friction":
        ratio = np.abs(ld.force_n[stretch, 0]) / np.maximum(fz, 1e-9)
        j = stretch[np.argmax(ratio)]
        return f"friction {ratio.max():.2f} needed at t = {ld.t_s[j]:.3f} s (the floor's is {lim.friction:g})"
    tau = np.abs(ld.torque_nm[stretch, what])
    j = stretch[np.argmax(tau)]
    return (f"{_joint_words(int(what), over_now)} {tau.max():.0f} N m at t = {ld.t_s[j]:.3f} s "
            f"(limit {lim.torque_nm[what]:.0f})")


def _joint_words(actuator: int, over_now: np.ndarray) -> str:
    """'lumbar needs', 'the hips need' (both sides over the limit), 'the right shoulder needs'."""
    ch = character()
    names = [ch.dof_names[i] for i in ch.actuated_dofs]
    base, _, side = names[actuator].partition("_")
    if not side:
        return f"{base} needs"
    other = names.index(f"{base}_{'l' if side == 'r' else 'r'}")
    if over_now[other]:
        return f"the {base}s need"
    return f"the {'right' if side == 'r' else 'left'} {base} needs"
