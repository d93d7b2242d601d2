"""A dual active-set QP solver, compiled, for the 3D plan's shape of problem: a cost whose Hessian is a dense block
(the joint accelerations') beside a diagonal one (the contact forces' regularization), a hundred two-sided rows,
most of them sparse, and an active set that changes little from one control step to the next.

    min 1/2 x'Hx + f'x   s.t.  lo <= A x <= hi   (a row with ``equality`` set: A x = hi),
    H = [[H_1, 0], [0, diag(h_2)]]

It is Goldfarb and Idnani's dual method (1983) on the least-distance form, as daqp (Arnstrom, Bemporad and Axehill
2022) solves it: with H = L L' and u = L'x + L^-1 f the problem is min 1/2 |u|^2 s.t. lo + m'v <= m'u <= hi + m'v
for each row's m = L^-1 a, v = L^-1 f. The iterates keep the multipliers of a working set non-negative and add the
most violated row until none is violated (optimal) or a violated row depends on the working set with no multiplier
to give way (infeasible). Why not daqp itself (the plan's first solver, which this agrees with to its tolerance:
tests/control/test_dual_qp.py): daqp factors the whole 55 x 55 cost and transforms every row by it - 54 us a
control step on this VM, as much as the 3D body's physics. Here the blocks make the factor a 31 x 31 one and a
force's transform a scaling; only the rows that enter the working set are transformed (the others are checked in
x, over their nonzeros); the dot products run over the rows' nonzero spans (two contact points' rows share none);
and the last control step's working set starts the next (``active``), so most steps need one factorization of the
working set's Gram matrix and one check of the rows.
"""

from __future__ import annotations

import numpy as np
from numba import njit

OPTIMAL, INFEASIBLE, ITERATION_LIMIT, NOT_CONVEX = 1, -1, -2, -3
INACTIVE, UPPER, LOWER, FIXED = 0, 1, -1, 2  # ``active``'s codes per row
MAX_ITERATIONS = 400
PRIMAL_TOL = 1e-10  # a row's violation, relative to the size of its terms
# floating-point freedoms for the compiled loops: sums reassociated (vectorized) and multiply-adds fused - never
# the freedom to assume no infinities (the bounds use them) or NaNs. Deterministic on one machine; another CPU's
# vector width may round differently (so may BLAS)
FAST = {"reassoc", "contract", "nsz", "arcp"}
DEPENDENT_TOL = 1e-10  # a row this close (in norm, rows scaled to unit length) to the working set's span depends on it


@njit(cache=True, nogil=True, fastmath=FAST)
def solve(H1, h2, f, A, lo, hi, equality, active):  # pragma: no cover - compiled
    """x (n,), status (OPTIMAL, INFEASIBLE, ITERATION_LIMIT, NOT_CONVEX) and the number of iterations. ``active``
    (m,) int8: the working set to start from (UPPER, LOWER; FIXED for equality rows is set here), updated in place
    to the solution's."""
    return solve_spanned(H1, h2, f, A, lo, hi, equality, active, spans(A))


@njit(cache=True, nogil=True, fastmath=FAST)
def solve_spanned(H1, h2, f, A, lo, hi, equality, active, span):  # pragma: no cover - compiled
    """``solve`` with each row's nonzero span given (m, 2): ``spans(A)``'s, from a caller that knows where its rows'
    nonzeros can be (``row_span``) - scanning every row of the 3D plan from both ends was a tenth of its QP."""
    n1, n = H1.shape[0], f.size
    m = A.shape[0]
    L = np.empty((n1, n1))
    if not _cholesky(H1, L):
        return np.zeros(n), NOT_CONVEX, 0
    root = np.sqrt(h2)
    v = np.zeros(n)
    _forward_from(L, f, 0, v)
    for j in range(n1, n):
        v[j] = f[j] / root[j - n1]
    # the least-distance rows (unit length), their bounds and nonzero spans, made when first needed
    M = np.empty((m, n))  # each row written over its span before it is read
    up, down = np.full(m, np.inf), np.full(m, -np.inf)
    mspan = np.zeros((m, 2), np.int64)
    made = np.zeros(m, np.bool_)
    qp = (L, root, v, A, lo, hi, span, M, up, down, mspan, made)
    for i in range(m):
        if equality[i]:
            active[i] = FIXED
        elif active[i] == FIXED:  # an equality last step
            active[i] = INACTIVE
        elif (active[i] == UPPER and not hi[i] < np.inf) or (active[i] == LOWER and not lo[i] > -np.inf):
            active[i] = INACTIVE  # a warm start on a side with no bound
        if span[i, 0] >= span[i, 1]:  # a row of zeros: feasible or not, whatever x
            if lo[i] > 1e-12 or hi[i] < -1e-12:
                return np.zeros(n), INFEASIBLE, 0
            active[i] = INACTIVE
        elif active[i] != INACTIVE:
            _make_row(qp, i)
    u, status, iterations = _dual_active_set(qp, active)
    return _x_of(L, root, v, u), status, iterations


@njit(cache=True, nogil=True, inline="always", fastmath=FAST)
def _dot(a, b):  # pragma: no cover - compiled
    """a . b as a plain loop: numba's np.dot calls BLAS, whose call costs more than these short vectors' sums."""
    s = 0.0
    for i in range(a.size):
        s += a[i] * b[i]
    return s


@njit(cache=True, nogil=True, fastmath=FAST)
def _cholesky(H, L):  # pragma: no cover - compiled
    """L (lower) with L L' = H; False where H is not positive definite."""
    n = H.shape[0]
    L[:] = 0.0
    for j in range(n):
        s = H[j, j] - _dot(L[j, :j], L[j, :j])
        if not s > 0.0:
            return False
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            L[i, j] = (H[i, j] - _dot(L[i, :j], L[j, :j])) / L[j, j]
    return True


@njit(cache=True, nogil=True, fastmath=FAST)
def _forward_from(L, a, first, out):  # pragma: no cover - compiled
    """out[:n1] = L^-1 a[:n1], where a's first ``first`` entries are zero (so are out's)."""
    n1 = L.shape[0]
    for i in range(first, n1):
        out[i] = (a[i] - _dot(L[i, first:i], out[first:i])) / L[i, i]


@njit(cache=True, nogil=True, fastmath=FAST)
def _x_of(L, root, v, u):  # pragma: no cover - compiled
    """x = L'^-1 (u - v)."""
    n1, n = L.shape[0], u.size
    x = np.empty(n)
    for j in range(n1, n):
        x[j] = (u[j] - v[j]) / root[j - n1]
    for i in range(n1 - 1, -1, -1):
        s = u[i] - v[i]
        for k in range(i + 1, n1):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]
    return x


@njit(cache=True, nogil=True, fastmath=FAST)
def spans(A):  # pragma: no cover - compiled
    """Each row's nonzeros' span [first, last + 1); (n, n) for a row of zeros."""
    m, n = A.shape
    span = np.zeros((m, 2), np.int64)
    for i in range(m):
        row_span(A, i, 0, n, span)
    return span


@njit(cache=True, nogil=True, inline="always")
def row_span(A, i, first, end, span):  # pragma: no cover - compiled
    """Row i's span into ``span[i]``, scanning only [first, end): the row's whole span where it is zero outside
    that window, as ``spans`` finds it ((n, n) for a row of zeros)."""
    n = A.shape[1]
    a = first
    while a < end and A[i, a] == 0.0:
        a += 1
    if a == end:
        span[i, 0], span[i, 1] = n, n
        return
    b = end
    while b > a and A[i, b - 1] == 0.0:
        b -= 1
    span[i, 0], span[i, 1] = a, b


@njit(cache=True, nogil=True, fastmath=FAST)
def _make_row(qp, i):  # pragma: no cover - compiled
    """Row i in the least-distance space: m = L^-1 a scaled to unit length, its bounds shifted by m'v alike; its
    span runs from a's first nonzero to the end of the dense block (the solve fills it) or a's last."""
    L, root, v, A, lo, hi, span, M, up, down, mspan, made = qp
    if made[i]:
        return
    n1 = L.shape[0]
    a0, a1 = span[i, 0], span[i, 1]
    if a0 < n1:
        _forward_from(L, A[i], a0, M[i])
    for j in range(max(a0, n1), a1):
        M[i, j] = A[i, j] / root[j - n1]
    end = max(a1, n1) if a0 < n1 else a1
    norm = np.sqrt(_dot(M[i, a0:end], M[i, a0:end]))
    shift = _dot(M[i, a0:end], v[a0:end])
    M[i, a0:end] /= norm
    up[i] = (hi[i] + shift) / norm
    down[i] = (lo[i] + shift) / norm
    mspan[i, 0], mspan[i, 1] = a0, end
    made[i] = True


@njit(cache=True, nogil=True, fastmath=FAST)
def _row_dot(M, mspan, i, k):  # pragma: no cover - compiled
    """m_i . m_k over their spans' overlap."""
    a, b = max(mspan[i, 0], mspan[k, 0]), min(mspan[i, 1], mspan[k, 1])
    return _dot(M[i, a:b], M[k, a:b]) if a < b else 0.0


@njit(cache=True, nogil=True, fastmath=FAST)
def _working_rows(qp, active):  # pragma: no cover - compiled
    """The working set as (row indices, signs: +1 upper or fixed, -1 lower, bounds b with sign * m'u <= b), fixed
    rows first."""
    up, down = qp[8], qp[9]
    m = active.size
    idx = np.empty(m, np.int64)
    sign = np.empty(m)
    k = 0
    for fixed in (True, False):
        for i in range(m):
            if active[i] != INACTIVE and (active[i] == FIXED) == fixed:
                idx[k] = i
                sign[k] = -1.0 if active[i] == LOWER else 1.0
                k += 1
    b = np.empty(k)
    for a in range(k):
        b[a] = -down[idx[a]] if sign[a] < 0 else up[idx[a]]
    return idx[:k], sign[:k], b


@njit(cache=True, nogil=True, fastmath=FAST)
def _gram_cholesky(qp, idx, sign, Lg):  # pragma: no cover - compiled
    """Lg (k, k) with Lg Lg' = R R' for the working rows R; False where they are (nearly) dependent."""
    M, mspan = qp[7], qp[10]
    k = idx.size
    for a in range(k):
        for c in range(a + 1):
            g = sign[a] * sign[c] * _row_dot(M, mspan, idx[a], idx[c]) - _dot(Lg[a, :c], Lg[c, :c])
            if c == a:
                if not g > DEPENDENT_TOL ** 2:
                    return False
                Lg[a, a] = np.sqrt(g)
            else:
                Lg[a, c] = g / Lg[c, c]
    return True


@njit(cache=True, nogil=True, fastmath=FAST)
def _stationary(Lg, b):  # pragma: no cover - compiled
    """The multipliers with the working rows all met: (R R') lam = -b, through Gram's Cholesky factor Lg."""
    k = b.size
    y = -b
    for i in range(k):
        y[i] = (y[i] - _dot(Lg[i, :i], y[:i])) / Lg[i, i]
    for i in range(k - 1, -1, -1):
        s = y[i]
        for j in range(i + 1, k):
            s -= Lg[j, i] * y[j]
        y[i] = s / Lg[i, i]
    return y


@njit(cache=True, nogil=True, fastmath=FAST)
def _primal(qp, idx, sign, lam):  # pragma: no cover - compiled
    """u = -R' lam."""
    M, mspan = qp[7], qp[10]
    u = np.zeros(M.shape[1])
    for a in range(idx.size):
        i = idx[a]
        w = sign[a] * lam[a]
        for j in range(mspan[i, 0], mspan[i, 1]):
            u[j] -= w * M[i, j]
    return u


@njit(cache=True, nogil=True, fastmath=FAST)
def _most_violated(qp, active, u):  # pragma: no cover - compiled
    """The row outside the working set that u violates most - checked in x, over each row's nonzeros, the violation
    over the row's size - and on which side (-1 if none)."""
    L, root, v, A, lo, hi, span = qp[0], qp[1], qp[2], qp[3], qp[4], qp[5], qp[6]
    x = _x_of(L, root, v, u)
    worst, row, side = 0.0, -1, INACTIVE
    for i in range(A.shape[0]):
        if active[i] != INACTIVE:
            continue
        s, size, norm = 0.0, 0.0, 0.0
        for j in range(span[i, 0], span[i, 1]):
            t = A[i, j] * x[j]
            s += t
            size += abs(t)
            norm += A[i, j] * A[i, j]
        tol = PRIMAL_TOL * (1.0 + size)
        if s - hi[i] > tol * (1.0 + abs(hi[i])) and (s - hi[i]) / np.sqrt(norm) > worst:
            worst, row, side = (s - hi[i]) / np.sqrt(norm), i, UPPER
        if lo[i] - s > tol * (1.0 + abs(lo[i])) and (lo[i] - s) / np.sqrt(norm) > worst:
            worst, row, side = (lo[i] - s) / np.sqrt(norm), i, LOWER
    return row, side


@njit(cache=True, nogil=True, fastmath=FAST)
def _dual_active_set(qp, active):  # pragma: no cover - compiled
    """The least-distance problem's u from the working set ``active`` (updated in place), its status and
    iterations."""
    m, n = qp[7].shape
    Lg = np.empty((m + 1, m + 1))  # each factorization writes what it reads
    # a dual feasible start: the warm working set without the rows whose multipliers would be negative
    while True:
        idx, sign, b = _working_rows(qp, active)
        if not _gram_cholesky(qp, idx, sign, Lg):  # a warm set that became dependent: start from the fixed rows
            for i in range(m):
                if active[i] != FIXED:
                    active[i] = INACTIVE
            idx, sign, b = _working_rows(qp, active)
            if not _gram_cholesky(qp, idx, sign, Lg):
                return np.zeros(n), INFEASIBLE, 0
        lam = _stationary(Lg, b)
        worst, at = 0.0, -1
        for a in range(idx.size):
            if active[idx[a]] != FIXED and lam[a] < worst:
                worst, at = lam[a], a
        if at < 0:
            break
        active[idx[at]] = INACTIVE
    for iteration in range(MAX_ITERATIONS):
        u = _primal(qp, idx, sign, lam)
        j, side = _most_violated(qp, active, u)
        if j < 0:
            return u, OPTIMAL, iteration
        _make_row(qp, j)
        # j joins with multiplier 0; where it depends on the working set, a row gives way first
        active[j] = side
        lam_j = 0.0
        while True:
            idx2, sign2, b2 = _working_rows(qp, active)
            if _gram_cholesky(qp, idx2, sign2, Lg):
                break
            active[j] = INACTIVE  # dependent: r_j = R' p; raise lam_j by t, lower lam by t p (u unchanged)
            p = _span_coefficients(qp, idx, sign, j, -1.0 if side == LOWER else 1.0)
            t, out = np.inf, -1
            for a in range(idx.size):
                if active[idx[a]] != FIXED and p[a] > 1e-12 and lam[a] / p[a] < t:
                    t, out = lam[a] / p[a], a
            if out < 0:
                return u, INFEASIBLE, iteration
            lam = lam - t * p
            lam_j += t
            active[idx[out]] = INACTIVE
            keep = np.ones(idx.size, np.bool_)
            keep[out] = False
            idx, sign, lam = idx[keep], sign[keep], lam[keep]
            active[j] = side
        lam = _with_row(idx, lam, idx2, j, lam_j)
        idx, sign, b = idx2, sign2, b2
        # step toward the working set's stationary multipliers, dropping a row whose multiplier reaches 0 first
        while True:
            target = _stationary(Lg, b)
            alpha, out = 1.0, -1
            for a in range(idx.size):
                if active[idx[a]] != FIXED and target[a] < 0.0:
                    step = lam[a] / (lam[a] - target[a])
                    if step < alpha:
                        alpha, out = step, a
            lam = lam + alpha * (target - lam)
            if out < 0:
                break
            active[idx[out]] = INACTIVE
            idx, sign, b = _working_rows(qp, active)
            lam = _without(lam, out)
            if not _gram_cholesky(qp, idx, sign, Lg):  # removing a row cannot make the rest dependent
                return _primal(qp, idx, sign, lam), INFEASIBLE, iteration
    return _primal(qp, idx, sign, lam), ITERATION_LIMIT, MAX_ITERATIONS


@njit(cache=True, nogil=True, fastmath=FAST)
def _span_coefficients(qp, idx, sign, j, side):  # pragma: no cover - compiled
    """p with R' p = r_j (row j with its side's sign), r_j in the span of the working rows R: (R R') p = R r_j."""
    M, mspan = qp[7], qp[10]
    k = idx.size
    G = np.empty((k, k))
    Rr = np.empty(k)
    for a in range(k):
        Rr[a] = sign[a] * side * _row_dot(M, mspan, idx[a], j)
        for c in range(k):
            G[a, c] = sign[a] * sign[c] * _row_dot(M, mspan, idx[a], idx[c])
    return np.linalg.lstsq(G, Rr)[0] if k > 0 else np.zeros(0)


@njit(cache=True, nogil=True, fastmath=FAST)
def _with_row(idx, lam, idx2, j, lam_j):  # pragma: no cover - compiled
    """The multipliers of working set ``idx2`` (``idx`` and row ``j``, reordered): j's is lam_j."""
    out = np.zeros(idx2.size)
    for a in range(idx2.size):
        if idx2[a] == j:
            out[a] = lam_j
            continue
        for c in range(idx.size):
            if idx[c] == idx2[a]:
                out[a] = lam[c]
                break
    return out


@njit(cache=True, nogil=True, fastmath=FAST)
def _without(lam, out):  # pragma: no cover - compiled
    """lam without entry ``out`` (the working set keeps its order when a row leaves)."""
    res = np.empty(lam.size - 1)
    res[:out] = lam[:out]
    res[out:] = lam[out + 1:]
    return res
