"""Angle arithmetic of the record-pole pattern search (:mod:`~mbus_framework.estimation.poles`).

A pattern's mode angles per unit time scale omega_j h, scaled by c, fold into [0, pi]; each
measured pole angle phi_i contributes min(min_j |fold(c omega_j h) - phi_i|, cap)^2. Here: the
scales at which some mode lands exactly on some measured angle, and the least cost over them
per pattern (exactly, with a cheap rounded pre-score)."""
from __future__ import annotations

import numpy as np

#: Largest angle distance [rad] a measured pole contributes (a pole the model cannot explain).
ANGLE_CAP = 0.05


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
