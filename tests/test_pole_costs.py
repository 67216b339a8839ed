"""The record-pole search's fast arithmetic against direct references: the angle cost by
neighbours against the (C, M, n) minimum, the batched best scale against ``np.argmin``
pattern by pattern, and the batched forward-difference Jacobian against scipy's own."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize._numdiff import approx_derivative

from mbus_framework.estimation.pole_angles import ANGLE_CAP, _angle_costs, _best_scales, _fold
from mbus_framework.estimation.poles import _forward_steps


def direct_costs(omega_h, phi, lnc):
    ang = _fold(np.exp(lnc)[:, None] * omega_h[None, :])
    d = np.abs(ang[:, None, :] - phi[None, :, None]).min(axis=2)
    return (np.minimum(d, ANGLE_CAP) ** 2).sum(axis=1)


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 14), m=st.integers(1, 13), c=st.integers(1, 300), seed=st.integers(0, 2**16),
       ties=st.booleans(), edge=st.booleans())
def test_angle_costs_equal_the_direct_minimum_exactly(n, m, c, seed, ties, edge):
    rng = np.random.default_rng(seed)
    omega_h = rng.uniform(0.0, 5.0, n)
    phi = rng.uniform(0.0, np.pi, m)
    if ties:  # repeated modes and repeated measured angles
        omega_h[: n // 2] = omega_h[0]
        phi[: m // 2] = phi[0]
    if edge:  # a measured angle at pi and one on a model angle
        phi[-1] = np.pi
        phi[0] = _fold(np.array([omega_h[0]]))[0]
    lnc = np.r_[0.0, rng.uniform(-3.0, 3.0, c)]
    np.testing.assert_array_equal(_angle_costs(omega_h, phi, lnc), direct_costs(omega_h, phi, lnc))


def test_best_scales_equal_argmin_pattern_by_pattern():
    rng = np.random.default_rng(3)
    phi = rng.uniform(0.0, np.pi, 9)
    omegas = [rng.uniform(0.0, 4.0, rng.choice([4, 10])) for _ in range(40)]
    lncs = [rng.uniform(-2.0, 2.0, rng.integers(1, 2000)) for _ in omegas]
    lncs[5] = np.zeros(3)  # equal costs: the first index, as np.argmin
    for (j, cost), w, lnc in zip(_best_scales(omegas, phi, lncs), omegas, lncs):
        ref = direct_costs(w, phi, lnc)
        assert j == int(np.argmin(ref)) and cost == ref[j]


def test_forward_steps_give_scipys_two_point_jacobian():
    def fun(x):
        return np.array([np.sin(x[0]) * x[1], np.exp(0.3 * x[2]) - x[0] ** 2, x[1] * x[2] + x[3]])

    for x in (np.array([0.3, -2.0, 1e-9, 5.0]), np.array([0.0, 1.0, -1e3, 2.5e7])):
        xs, dx = _forward_steps(x, 1e-7)
        f0 = fun(x)
        J = np.array([(fun(xi) - f0) / d for xi, d in zip(xs, dx)]).T
        ref = approx_derivative(fun, x, rel_step=1e-7, method="2-point", f0=f0)
        np.testing.assert_array_equal(J, ref)


def test_scale_candidates_batch_equal_the_single_pattern_ones_exactly():
    """Every pattern's alias crossings from the batched enumeration are the same numbers as
    :func:`_scale_candidates` of that pattern alone (mode counts mixed, empty patterns, phi = pi,
    ranges without crossings, batches smaller than a group)."""
    from mbus_framework.estimation.pole_angles import _scale_candidates, _scale_candidates_batch

    rng = np.random.default_rng(7)
    for trial in range(60):
        R, M = int(rng.integers(1, 30)), int(rng.integers(1, 10))
        phi = np.sort(rng.uniform(0.0, np.pi, M))
        if trial % 4 == 0:
            phi[-1] = np.pi
        omegas = [np.exp(rng.uniform(-6.0, 1.0, int(rng.integers(0, 5)))) for _ in range(R)]
        lo = rng.uniform(-3.0, 1.0, R)
        hi = lo + rng.uniform(0.0, 5.0, R)
        got = _scale_candidates_batch(omegas, phi, lo, hi, rows=int(rng.integers(1, 8)))
        for w, a, b, g in zip(omegas, lo, hi, got):
            np.testing.assert_array_equal(g, _scale_candidates(w, phi, a, b))


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 14), m=st.integers(1, 13), c=st.integers(1, 300), seed=st.integers(0, 2**16),
       crowded=st.booleans(), far=st.booleans())
def test_rounded_angle_costs_stay_within_their_bound(n, m, c, seed, crowded, far):
    """The cheap cost (rint fold, binned lookup of the near measured angles) differs from the
    exact one by no more than the bound it returns: measured angles crowded within the cap of
    each other (several near one bin), at 0 and pi, and scales far up the aliases."""
    from mbus_framework.estimation.pole_angles import _angle_costs_rounded

    rng = np.random.default_rng(seed)
    omega_h = rng.uniform(0.0, 5.0, n)
    phi = rng.uniform(0.0, np.pi, m)
    if crowded:
        phi = 1.0 + rng.uniform(-1.5, 1.5, m) * ANGLE_CAP
        phi[0], phi[-1] = 0.0, np.pi
    lnc = rng.uniform(-3.0, 9.0 if far else 3.0, c)
    row = np.zeros(c, dtype=np.intp)
    rounded, bound = _angle_costs_rounded(omega_h[None, :], phi, lnc, row)
    exact = _angle_costs(omega_h, phi, lnc)
    assert bound < 1e-9
    assert np.all(np.abs(rounded - exact) <= bound)


def test_near_angles_hold_every_measured_angle_within_the_cap_of_a_bin():
    """Every measured angle within the cap of an angle in a bin is listed for that bin (the
    reference: the distance of each measured angle to a fine grid of angles in each bin)."""
    from mbus_framework.estimation.pole_angles import ANGLE_BINS, _near_angles

    rng = np.random.default_rng(5)
    phi = np.r_[0.0, np.pi, rng.uniform(0.0, np.pi, 9), 1.0 + np.arange(5) * 0.3 * ANGLE_CAP]
    table = _near_angles(phi)
    w = np.pi / ANGLE_BINS
    for b in range(ANGLE_BINS):
        grid = b * w + np.linspace(0.0, w, 9)
        need = np.flatnonzero(np.abs(grid[:, None] - phi[None, :]).min(axis=0) <= ANGLE_CAP)
        assert set(need) <= set(table[b]), b
    assert np.all((table >= 0) & (table <= phi.size))
