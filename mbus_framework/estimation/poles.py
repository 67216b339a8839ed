"""Starts from the record's poles: subspace identification, then matching the model's poles.

A lightly damped chain (damping ratios 1e-4 to 1e-2) rings at its modes for the whole record:
every mode is a spectral line a fraction of a per cent wide. The output-error cost then has a
basin a fraction of a per cent wide along the time scale *and* along every stiffness ratio
(the ratios set the spacing of the modes), which a scan of the spectral cost on a
logarithmic grid (:mod:`~mbus_framework.estimation.global_search`) cannot resolve, all the
more when modes lie above the Nyquist frequency and alias. The record's poles locate that
basin directly:

1. **Record poles, model-free.** PO-MOESP subspace identification (Verhaegen 1994) of a
   discrete state-space model of the model's order from (u, y): the past inputs and outputs
   are the instruments, so white output noise does not bias the poles. Its eigenvalues
   z_i are the record's discrete poles (aliasing included: z = e^{s h}).
2. **Frequency pattern.** With every damping-like parameter at its least value, a fine design
   over the stiffness ratios (the shape directions of the parameters with the largest time
   exponent) gives the undamped pole pattern s_j; scaling time by c moves every angle to
   c Im(s_j) h. The scales at which one model angle lands on one measured angle (modulo 2 pi,
   folded into [0, pi]) are enumerated exactly, and each is scored by the capped angle
   distance of every measured pole to its nearest model pole.
3. **All parameters.** The best patterns are refined by least squares on the capped complex
   distances |z_i - e^{s_j(theta) h}| in ln theta (dampings from the pole radii).

The candidates then start time-domain fits (:mod:`~mbus_framework.estimation.strategy`),
which accept or reject them by the noise level like any other start.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from mbus_framework.engine.simulation import as_float_ss
from mbus_framework.estimation.global_search import Candidate, SearchSpace, distinct, sobol

#: Largest angle distance [rad] a measured pole contributes (a pole the model cannot explain).
ANGLE_CAP = 0.05
#: Largest complex distance a measured pole contributes in the refinement.
POLE_CAP = 0.05


def _block_hankel(x: np.ndarray, rows: int, cols: int, start: int) -> np.ndarray:
    return np.lib.stride_tricks.sliding_window_view(x[start:start + rows + cols - 1], cols)[:rows]


#: Columns of the block-Hankel data matrix factorised at a time (memory O(4 s CHUNK)).
CHUNK = 8192


def _lq_factor(u: np.ndarray, y: np.ndarray, s: int, cols: int, chunk: int = CHUNK) -> np.ndarray:
    """R (4s, 4s) of the QR factorisation of M^T, M = [U_f; U_p; Y_p; Y_f] (4s x cols),
    built chunk by chunk: R = qr([R_prev; M_chunk^T]) (time O(s^2 cols), memory O(s chunk)),
    so the record's length costs linear time and constant memory."""
    R = np.zeros((0, 4 * s))
    for c0 in range(0, cols, chunk):
        c1 = min(cols, c0 + chunk)

        def block(x: np.ndarray, start: int) -> np.ndarray:
            return _block_hankel(x[c0:], s, c1 - c0, start)

        Mc = np.vstack([block(u, s), block(u, 0), block(y, 0), block(y, s)])
        R = np.linalg.qr(np.vstack([R, Mc.T]), mode="r")
    return R


def record_poles(u: np.ndarray, y: np.ndarray, order: int, horizon: int | None = None) -> np.ndarray:
    """Discrete poles of a PO-MOESP state-space model of ``order`` identified from (u, y).

    ``horizon`` s (default max(2 order, order + 10)) block rows of past and future data;
    the extended observability matrix is the leading ``order`` left singular vectors of the
    part of the future outputs explained by past inputs and outputs after the future inputs
    are removed (LQ factorisation), and A follows from its shift invariance."""
    u = np.asarray(u, float).ravel()
    y = np.asarray(y, float).ravel()
    s = int(horizon or max(2 * order, order + 10))
    cols = len(u) - 2 * s + 1
    if order < 1 or cols < 4 * s:
        return np.empty(0, complex)
    su, sy = float(np.std(u)), float(np.std(y))
    if not (su > 0 and sy > 0 and np.isfinite(su) and np.isfinite(sy)):
        return np.empty(0, complex)
    u, y = u / su, y / sy
    L = _lq_factor(u, y, s, cols).T
    L32 = L[3 * s:, s:3 * s]
    U, sv, _ = np.linalg.svd(L32, full_matrices=False)
    G = U[:, :order] * sv[:order]
    A = np.linalg.lstsq(G[:-1], G[1:], rcond=None)[0]
    z = np.linalg.eigvals(A)
    return z[np.isfinite(z) & (np.abs(z) < 1.0)]


def _state_matrices(model, thetas: np.ndarray) -> np.ndarray:
    """A (N, n, n) of every row of ``thetas``: the model's batched assembly
    (:meth:`~mbus_framework.engine.chain.ChainModel.state_matrices_batch`, the same numbers)
    where it has one, else ``state_space`` row by row."""
    with np.errstate(all="ignore"):
        batch = getattr(model, "state_matrices_batch", None)
        if batch is not None:
            return batch(thetas)
        return np.array([as_float_ss(model.state_space(th)).A for th in thetas])


def _continuous_poles(model, theta: np.ndarray) -> np.ndarray:
    with np.errstate(all="ignore"):
        A = as_float_ss(model.state_space(theta)).A
        if not np.all(np.isfinite(A)):
            return np.empty(0, complex)
        return np.linalg.eigvals(A)


def _continuous_poles_batch(model, thetas: np.ndarray) -> list[np.ndarray]:
    """:func:`_continuous_poles` of every row of ``thetas``: one stacked eigenvalue call (the
    same LAPACK routine per matrix, without the per-call overhead)."""
    thetas = np.asarray(thetas, float)
    if thetas.shape[0] == 0:
        return []
    mats = _state_matrices(model, thetas)
    finite = np.all(np.isfinite(mats), axis=(1, 2))
    out = [np.empty(0, complex)] * len(mats)
    rows = np.flatnonzero(finite)
    if rows.size:
        lam = np.linalg.eigvals(mats[rows])
        for k, l in zip(rows, lam):
            out[k] = l
    return out


def _fold(angle: np.ndarray) -> np.ndarray:
    """Angles folded into [0, pi] (a pole and its conjugate, aliasing included)."""
    return np.abs(np.mod(angle + np.pi, 2 * np.pi) - np.pi)


def _scale_candidates(omega_h: np.ndarray, phi: np.ndarray, lnc_lo: float, lnc_hi: float) -> np.ndarray:
    """ln c at which some c omega_j h equals some +-phi_i modulo 2 pi, within [lnc_lo, lnc_hi]:
    c = (2 pi k +- phi_i) / (omega_j h) for every alias k of every mode (modes with more than
    64 aliases in the range skipped: more than a record can tell apart); all modes at once."""
    c_lo, c_hi = np.exp(lnc_lo), np.exp(lnc_hi)
    w = omega_h[omega_h > 0]
    k_lo, k_hi = np.floor(c_lo * w / (2 * np.pi)), np.floor(c_hi * w / (2 * np.pi)) + 1
    keep = k_hi - k_lo <= 64
    w, k_lo, k_hi = w[keep], k_lo[keep], k_hi[keep]
    if w.size == 0:
        return np.empty(0)
    k = k_lo[:, None] + np.arange(int((k_hi - k_lo).max()) + 1)[None, :]  # (modes, aliases)
    two_pi_k, wj = (2 * np.pi * k)[:, :, None], w[:, None, None]
    with np.errstate(over="ignore"):  # a vanishing mode frequency: c beyond any range
        c = np.stack([(two_pi_k + phi) / wj, (two_pi_k - phi) / wj])  # (2, modes, aliases, measured)
    c = c[(k <= k_hi[:, None])[None, :, :, None] & (c >= c_lo) & (c <= c_hi)]
    if c.size == 0:
        return np.empty(0)
    c = np.unique(c)  # phi = pi: alias k + phi and alias k + 1 - phi are one crossing, apart by rounding
    return np.log(c[np.r_[True, np.diff(c) > 1e-12 * c[1:]]])


def _scale_candidates_batch(omegas: list[np.ndarray], phi: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                            rows: int = 128) -> list[np.ndarray]:
    """:func:`_scale_candidates` of every pattern (``omegas[r]`` its mode angles per unit scale,
    ``lo[r]``, ``hi[r]`` its ln c range), the same numbers, with the patterns of one mode count
    done together (``rows`` at a time): one (2, rows, modes, aliases, measured) array, one
    sort by (pattern, c) and the same duplicate rule within each pattern."""
    out: list[np.ndarray] = [np.empty(0)] * len(omegas)
    pos = [w[w > 0] for w in omegas]
    groups: dict[int, list[int]] = {}
    for r, w in enumerate(pos):
        if w.size:
            groups.setdefault(w.size, []).append(r)
    for members in groups.values():
        for a in range(0, len(members), rows):
            idx = np.array(members[a : a + rows])
            w = np.array([pos[r] for r in idx])  # (R, n)
            c_lo, c_hi = np.exp(np.asarray(lo, float)[idx])[:, None], np.exp(np.asarray(hi, float)[idx])[:, None]
            k_lo, k_hi = np.floor(c_lo * w / (2 * np.pi)), np.floor(c_hi * w / (2 * np.pi)) + 1
            keep = k_hi - k_lo <= 64
            if not keep.any():
                continue
            k = k_lo[:, :, None] + np.arange(int((k_hi - k_lo)[keep].max()) + 1)  # (R, n, aliases)
            two_pi_k, wj = (2 * np.pi * k)[..., None], w[:, :, None, None]
            with np.errstate(over="ignore"):
                c = np.stack([(two_pi_k + phi) / wj, (two_pi_k - phi) / wj])  # (2, R, n, aliases, M)
            valid = ((k <= k_hi[:, :, None]) & keep[:, :, None])[None, ..., None]
            valid = valid & (c >= c_lo[None, :, :, None, None]) & (c <= c_hi[None, :, :, None, None])
            row = np.broadcast_to(np.arange(idx.size)[None, :, None, None, None], c.shape)[valid]
            c = c[valid]
            if c.size == 0:
                continue
            order = np.lexsort((c, row))
            c, row = c[order], row[order]
            first = np.r_[True, row[1:] != row[:-1]]
            new = first | np.r_[True, np.diff(c) > 1e-12 * c[1:]]  # exact repeats fail the test too
            c, row = c[new], row[new]
            bounds = np.searchsorted(row, np.arange(idx.size + 1))
            for j, r in enumerate(idx):
                if bounds[j + 1] > bounds[j]:
                    out[r] = np.log(c[bounds[j] : bounds[j + 1]])
    return out


def _angle_costs(omega_h: np.ndarray, phi: np.ndarray, lnc: np.ndarray, row: np.ndarray | None = None) -> np.ndarray:
    """sum_i min(min_j |fold(c omega_j h) - phi_i|, cap)^2 for every c = e^lnc.

    ``omega_h`` (n,) one pattern's mode angles per unit scale, or (R, n) several patterns
    with ``row`` (C,) naming each scale's pattern (all patterns in one pass).

    The nearest model angle to phi_i is the largest angle <= phi_i or the smallest >= phi_i:
    with the model angles of each c sorted, the count of angles below each phi_i (one
    bincount of their slots between the sorted phi) picks both neighbours, so the work is
    O(C (n + M)) instead of O(C n M); the distances are the same floating-point numbers as
    the direct minimum (|a - phi| = phi - a exactly, and rounding is monotone)."""
    omega = np.atleast_2d(omega_h)
    row = np.zeros(lnc.size, dtype=np.intp) if row is None else row
    ang = np.sort(_fold(np.exp(lnc)[:, None] * omega[row]), axis=1)  # (C, n)
    C, n = ang.shape
    order = np.argsort(phi, kind="stable")
    ps = phi[order]
    M = ps.size
    slot = np.searchsorted(ps, ang, side="left")  # number of phi below each angle, (C, n)
    counts = np.bincount((np.arange(C)[:, None] * (M + 1) + slot).ravel(), minlength=C * (M + 1))
    below = np.cumsum(counts.reshape(C, M + 1), axis=1)[:, :M]  # angles <= ps_i, (C, M)
    rows = np.arange(C)[:, None]
    lower = np.where(below > 0, ang[rows, np.maximum(below - 1, 0)], -np.inf)
    upper = np.where(below < n, ang[rows, np.minimum(below, n - 1)], np.inf)
    d_sorted = np.minimum(ps - lower, upper - ps)
    d = np.empty_like(d_sorted)
    d[:, order] = d_sorted  # back to the measured poles' order (the same sum as the direct form)
    return (np.minimum(d, ANGLE_CAP) ** 2).sum(axis=1)


#: Bins over [0, pi] of the measured-angle table of :func:`_angle_costs_rounded` (width cap / 4).
ANGLE_BINS = int(np.ceil(4 * np.pi / ANGLE_CAP))


def _near_angles(phi: np.ndarray, bins: int = ANGLE_BINS) -> np.ndarray:
    """(bins, K) indices of the measured angles within ``ANGLE_CAP`` (plus a rounding margin)
    of some angle of each bin of [0, pi], padded with ``phi.size``."""
    w = np.pi / bins
    lo, hi = np.arange(bins) * w - ANGLE_CAP - 1e-6 * w, (np.arange(bins) + 1) * w + ANGLE_CAP + 1e-6 * w
    near = (phi[None, :] >= lo[:, None]) & (phi[None, :] <= hi[:, None])  # (bins, M)
    K = max(int(near.sum(axis=1).max()), 1)
    order = np.argsort(~near, axis=1, kind="stable")[:, :K]  # the near ones first
    return np.where(np.take_along_axis(near, order, axis=1), order, phi.size)


def _angle_costs_rounded(omega_h: np.ndarray, phi: np.ndarray, lnc: np.ndarray,
                         row: np.ndarray) -> tuple[np.ndarray, float]:
    """:func:`_angle_costs` to rounding, cheaply, and a bound on its difference from it.

    The angles fold as |t - 2 pi rint(t / 2 pi)| (no ``np.mod``); only a measured angle within
    the cap of a model angle lowers its term below cap^2, and those are looked up by the model
    angle's bin (:func:`_near_angles`), their distances taking the least per (scale, measured
    angle) in one unbuffered ``np.minimum.at``: O(C n K) with K the most measured angles near
    one bin, no sort. Both folds are |t - 2 pi k| to a few ulp of t, so every angle differs
    by at most delta = 8 eps (max t + 4); a capped square then by 2 cap delta + delta^2, a sum
    of M of them by M times that plus its own rounding. The bound returned is four times that."""
    t = np.exp(lnc)[:, None] * omega_h[row]  # (C, n), the same numbers as _angle_costs
    ang = np.abs(t - 2 * np.pi * np.rint(t * (0.5 / np.pi)))
    C, M = t.shape[0], phi.size
    table = _near_angles(phi)
    ang = ang.ravel()
    b = np.minimum((ang * (ANGLE_BINS / np.pi)).astype(np.intp), ANGLE_BINS - 1)
    scale = np.arange(ang.size) // t.shape[1]
    nearest = np.full(C * M, ANGLE_CAP)  # min(d, cap) per (scale, measured angle)
    for k in range(table.shape[1]):
        i = table[:, k][b]
        at = np.flatnonzero(i < M)  # the model angles with a k-th measured angle near
        i = i[at]
        np.minimum.at(nearest, scale[at] * M + i, np.abs(ang[at] - phi[i]))
    cost = (nearest.reshape(C, M) ** 2).sum(axis=1)
    eps = np.finfo(float).eps
    delta = 8 * eps * (float(np.max(t, initial=0.0)) + 4.0)
    bound = M * (2 * ANGLE_CAP * delta + delta**2 + 2 * M * eps * ANGLE_CAP**2)
    return np.where(np.all(np.isfinite(t), axis=1), cost, np.nan), 4 * bound


#: Scales scored in one pass of :func:`_best_scales` (memory O(BATCH (n + M))).
BATCH = 4096


def _best_scales(omegas: list[np.ndarray], phi: np.ndarray, lncs: list[np.ndarray]) -> list[tuple[int, float]]:
    """(index of the least cost, cost) per pattern: ``np.argmin`` of :func:`_angle_costs`
    pattern by pattern, with the patterns of one mode count scored together.

    Every scale is first scored by :func:`_angle_costs_rounded`; only the scales within twice
    its error bound of their pattern's least rounded cost can hold the least exact cost
    (a pattern with a non-finite cost keeps all), and only those are scored exactly, so the
    index and cost are those of the exact costs of all scales."""
    out: list[tuple[int, float] | None] = [None] * len(omegas)
    groups: dict[int, list[int]] = {}
    for k, w in enumerate(omegas):
        groups.setdefault(w.size, []).append(k)
    for members in groups.values():
        start = 0
        while start < len(members):
            part, size = [], 0
            while start < len(members) and (not part or size + lncs[members[start]].size <= BATCH):
                part.append(members[start])
                size += lncs[members[start]].size
                start += 1
            sizes = np.array([lncs[k].size for k in part])
            row = np.repeat(np.arange(len(part)), sizes)
            W, lnc = np.array([omegas[k] for k in part]), np.concatenate([lncs[k] for k in part])
            first = np.r_[0, np.cumsum(sizes)[:-1]]
            rounded, bound = _angle_costs_rounded(W, phi, lnc, row)
            least = np.minimum.reduceat(rounded, first)
            near = (rounded <= (least + 2 * bound)[row]) | ~np.isfinite(least)[row]
            sel = np.flatnonzero(near)
            exact = _angle_costs(W, phi, lnc[sel], row[sel])
            bounds = np.searchsorted(sel, np.r_[first, lnc.size])
            for p, k in enumerate(part):
                a, b = bounds[p], bounds[p + 1]
                j = a + int(np.argmin(exact[a:b]))
                out[k] = (int(sel[j] - first[p]), float(exact[j]))
    return out


def _angle_costs_direct(omega_h: np.ndarray, phi: np.ndarray, lnc: np.ndarray) -> np.ndarray:
    """:func:`_angle_costs` by the direct (C, M, n) minimum (the reference for tests)."""
    ang = _fold(np.exp(lnc)[:, None] * omega_h[None, :])  # (C, n)
    d = np.abs(ang[:, None, :] - phi[None, :, None]).min(axis=2)  # (C, M)
    return (np.minimum(d, ANGLE_CAP) ** 2).sum(axis=1)


def pattern_search(problem, space: SearchSpace, z: np.ndarray, template: np.ndarray, points: int = 2048,
                   keep: int = 6, seed: int = 0) -> list[Candidate]:
    """The best distinct undamped frequency patterns against the measured poles (cost: the
    capped angle distances)."""
    mv = np.flatnonzero(space.movable)
    e = space.e[mv]
    if mv.size == 0 or not np.any(e > 0):
        return []
    phi = _fold(np.angle(z[np.imag(z) >= 0]))
    phi = phi[phi > 1e-6]
    if phi.size == 0:
        return []
    emax = e.max()
    stiff, soft = mv[e == emax], mv[e != emax]
    fixed = np.clip(template, space.lo, space.hi)
    with np.errstate(divide="ignore", invalid="ignore"):  # logs are used at movable (positive) entries only
        llo, lhi, base = np.log(space.lo), np.log(space.hi), np.log(fixed)

    def theta(lt: np.ndarray) -> np.ndarray:
        th = fixed.copy()
        th[mv] = np.exp(lt[mv])
        return th

    base[soft] = llo[soft]  # the least damping: undamped frequencies
    # shape: the stiffness ratios (log differences from the first stiffness parameter)
    if stiff.size == 1:
        ratios = np.zeros((1, 0))
    elif stiff.size == 2:
        ratios = np.linspace(-1.0, 1.0, points)[:, None]
    else:
        ratios = 2 * sobol(stiff.size - 1, points, seed) - 1
    rel_lo = llo[stiff[1:]] - lhi[stiff[0]]
    rel_hi = lhi[stiff[1:]] - llo[stiff[0]]
    ratios = rel_lo + (ratios + 1) / 2 * (rel_hi - rel_lo)
    h = problem.dt
    rows = []
    for r in ratios:
        lt = base.copy()
        lt[stiff[0]] = 0.5 * (llo[stiff[0]] + lhi[stiff[0]])
        lt[stiff[1:]] = lt[stiff[0]] + r
        # ln c range keeping every stiffness within the box (stiffness scales as c**emax)
        lnc_lo = np.max((llo[stiff] - lt[stiff]) / emax)
        lnc_hi = np.min((lhi[stiff] - lt[stiff]) / emax)
        if lnc_hi >= lnc_lo:
            rows.append((lt, lnc_lo, lnc_hi))
    poles = _continuous_poles_batch(problem.model, np.array([theta(lt) for lt, _, _ in rows])[:, : problem.n_model]
                                    if rows else np.empty((0, problem.n_model)))
    all_omegas = [np.abs(s.imag[s.imag > 0]) * h for s in poles]
    all_lncs = _scale_candidates_batch(all_omegas, phi, np.array([r[1] for r in rows]), np.array([r[2] for r in rows]))
    kept, omegas, lncs = [], [], []
    for (lt, _, _), omega_h, lnc in zip(rows, all_omegas, all_lncs):
        if omega_h.size == 0 or lnc.size == 0:
            continue
        kept.append(lt)
        omegas.append(omega_h)
        lncs.append(lnc)
    found: list[Candidate] = []
    for lt, lnc, (j, cost) in zip(kept, lncs, _best_scales(omegas, phi, lncs)):
        th = theta(lt)
        th[stiff] *= np.exp(emax * lnc[j])
        found.append(Candidate(th, cost, "poles"))
    return distinct(found, rtol=0.02, limit=keep)


#: Relative forward-difference step of the pole refinement's Jacobian.
DIFF_STEP = 1e-7


def _forward_steps(x: np.ndarray, rel_step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points x + h_i e_i (n, n) and the steps dx_i = (x_i + h_i) - x_i of a forward difference
    with h_i = rel_step sign(x_i) |x_i| (sign(0) = 1; sqrt(eps) max(1, |x_i|) where that step
    vanishes): the rule of ``scipy.optimize.least_squares(diff_step=rel_step)``, so the
    Jacobian equals its ``'2-point'`` one while all n points are evaluated in one batch."""
    x = np.asarray(x, float)
    sign = np.where(x >= 0, 1.0, -1.0)
    h = rel_step * sign * np.abs(x)
    h = np.where((x + h) - x == 0, np.sqrt(np.finfo(float).eps) * sign * np.maximum(1.0, np.abs(x)), h)
    xs = np.repeat(x[None, :], x.size, axis=0)
    idx = np.arange(x.size)
    xs[idx, idx] = x + h
    return xs, (x + h) - x


#: Evaluations over which a pole refinement's rate of progress is measured (:func:`refine_on_poles`).
PROGRESS_WINDOW = 20


class _CannotWin(Exception):
    """A pole refinement stopped: at its recent rate it cannot get below the cost to beat."""


def _cannot_win(best: list[float], max_nfev: int, beat: float, window: int = PROGRESS_WINDOW) -> bool:
    """True when the best cost so far (``best[k]`` after evaluation k), lowered for every
    evaluation left at its mean rate over the last ``window`` evaluations, stays above ``beat``:

        best_k - (best_{k-W} - best_k) / W * (max_nfev - k) > beat."""
    k = len(best) - 1
    if k < window or not np.isfinite(beat):
        return False
    rate = (best[k - window] - best[k]) / window
    return best[k] - rate * max(max_nfev - k, 0) > beat


def refine_on_poles(problem, space: SearchSpace, z: np.ndarray, theta: np.ndarray, max_nfev: int = 200,
                    beat: float = np.inf) -> Candidate:
    """Least squares in ln theta (movable entries) on the capped distances of the measured
    poles z to their nearest model poles. ``beat``: the cost this refinement must get below to
    be kept (:func:`pole_candidates`); a refinement that cannot at its recent rate of progress
    (:func:`_cannot_win`) stops early with its best point so far."""
    mv = np.flatnonzero(space.movable)
    h, n_model = problem.dt, problem.n_model
    theta = np.clip(np.asarray(theta, float), space.lo, space.hi)
    zlo, zhi = np.log(space.lo[mv]), np.log(space.hi[mv])

    def capped(s):
        if s.size == 0:
            return np.full(z.size, POLE_CAP)
        d = np.abs(z[:, None] - np.exp(s * h)[None, :]).min(axis=1)
        return np.minimum(d, POLE_CAP)

    def capped_rows(poles):  # capped() of every pole set (k, z.size): the same elementwise numbers
        out = np.full((len(poles), z.size), POLE_CAP)
        sizes = np.array([p.size for p in poles])
        for size in np.unique(sizes[sizes > 0]):
            rows = np.flatnonzero(sizes == size)
            e = np.exp(np.array([poles[k] for k in rows]) * h)  # (rows, n)
            out[rows] = np.minimum(np.abs(z[None, :, None] - e[:, None, :]).min(axis=2), POLE_CAP)
        return out

    def theta_of(x):
        th = theta.copy()
        th[mv] = np.exp(np.clip(x, zlo, zhi))
        return th

    def thetas_of(xs):  # theta_of() of every row of xs (k, n_model), the same elementwise numbers
        th = np.repeat(theta[None, :], len(xs), axis=0)
        th[:, mv] = np.exp(np.clip(xs, zlo, zhi))
        return th[:, :n_model]

    last: list = [None, None, None]  # the last residual evaluated: (x, r, its Jacobian's point poles)
    best: list[float] = []  # the least cost after each evaluation
    best_x: list = [None]

    def residual(x):
        # x and the Jacobian's points in one batch: the least-squares solver asks for the
        # Jacobian at nearly every residual it evaluates (every accepted step); the poles of
        # each point are the numbers evaluated one by one (the same matrices, and the stacked
        # eigenvalue routine runs matrix by matrix)
        xs, dx = _forward_steps(x, DIFF_STEP)
        try:
            poles = _continuous_poles_batch(problem.model, thetas_of(np.vstack([x, xs])))
            rows = capped_rows(poles)
            r, ahead = rows[0], (rows[1:], dx)
        except np.linalg.LinAlgError:  # a Jacobian point failed: the residual alone, as before
            r, ahead = capped(_continuous_poles(problem.model, theta_of(x)[:n_model])), None
        last[:] = [np.array(x, copy=True), r, ahead]
        cost = float(r @ r)
        if not best or cost < best[-1]:
            best_x[0] = last[0]
        best.append(min(cost, best[-1]) if best else cost)
        if _cannot_win(best, max_nfev, beat):
            raise _CannotWin
        return r

    def jacobian(x):
        if last[0] is None or not np.array_equal(last[0], x):
            residual(x)
        f0 = last[1]
        if last[2] is not None:
            rows, dx = last[2]
        else:
            xs, dx = _forward_steps(x, DIFF_STEP)
            rows = capped_rows(_continuous_poles_batch(problem.model, np.array([theta_of(xi)[:n_model] for xi in xs])))
        return ((rows - f0) / dx[:, None]).T

    # the pattern left every damping at its least value, where the pole radii barely move with
    # it: start from the best common position of the damping-like parameters in their range
    e = space.e[mv]
    soft = e != e.max()
    x0 = np.log(theta[mv])
    if soft.any():
        xs = np.repeat(x0[None, :], 41, axis=0)
        xs[:, soft] = zlo[soft] + np.linspace(0.0, 1.0, 41)[:, None] * (zhi[soft] - zlo[soft])
        poles = _continuous_poles_batch(problem.model, np.array([theta_of(x)[:n_model] for x in xs]))
        costs = [float(np.sum(r ** 2)) for r in capped_rows(poles)]
        x0 = xs[int(np.argmin(costs))]
    try:
        res = least_squares(residual, x0, jac=jacobian, method="trf", max_nfev=max_nfev, x_scale=1.0)
        x, cost = res.x, float(2 * res.cost)
    except _CannotWin:
        x, cost = best_x[0], best[-1]
    th = theta.copy()
    th[mv] = np.exp(np.clip(x, zlo, zhi))
    return Candidate(th, cost, "record poles")


def identified_poles(problem) -> np.ndarray:
    """:func:`record_poles` of the record at the model's order; empty when the model has no
    states or identification fails."""
    order = getattr(problem.model, "n_states", 0)
    if not getattr(problem.model, "has_state_space", True) or not order:
        return np.empty(0, complex)
    try:
        return record_poles(problem.u, problem.y, int(order))
    except (np.linalg.LinAlgError, ValueError, MemoryError):
        return np.empty(0, complex)


def pole_candidates(problem, space: SearchSpace, template: np.ndarray, limit: int = 3,
                    seed: int = 0, identify=identified_poles) -> list[Candidate]:
    """Starts whose pole pattern matches the record's poles, best first (empty when the
    model's time scaling is not exact, a compensator filters the output, or no poles are
    found); ``identify(problem)`` gives the record's poles (:func:`identified_poles`, or a
    search's poles identified once)."""
    if (not getattr(problem.model, "has_state_space", True) or not space.scaled or problem.output_filter is not None
            or not space.movable.any()):
        return []
    z = identify(problem)
    if z.size == 0:
        return []
    out = []
    for pattern in pattern_search(problem, space, z, template, seed=seed, keep=2 * limit):
        kept = distinct(out, rtol=0.01, limit=limit)
        beat = kept[-1].cost if len(kept) == limit else np.inf  # what a new refinement must get below
        try:
            out.append(refine_on_poles(problem, space, z, pattern.theta, beat=beat))
        except (np.linalg.LinAlgError, ValueError, FloatingPointError):
            continue
    return distinct(out, rtol=0.01, limit=limit)
