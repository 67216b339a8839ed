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
from mbus_framework.estimation.pole_angles import _best_scales, _fold, _scale_candidates_batch

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
