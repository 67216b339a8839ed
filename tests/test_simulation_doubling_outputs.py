"""The doubling path's projected outputs against a plain step-by-step recursion.

``krylov_outputs`` and ``krylov_sensitivity_outputs`` (:mod:`mbus_framework.engine.doubling`)
split the lags into baby and giant steps, both by doubling; the reference here
steps x[k+1] = Phi x[k] and the sensitivity system [[Phi, 0], [Psi_i, Phi]] one sample at a
time, for lengths on and off the powers of two (every schedule shape)."""
from __future__ import annotations

import numpy as np
import pytest

from mbus_framework.engine import doubling


def _system(n, p, seed):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    Phi = 0.97 * A / np.abs(np.linalg.eigvals(A)).max()  # spectral radius 0.97: stays bounded
    return (Phi, 0.05 * rng.normal(size=(p, n, n)), rng.normal(size=n), rng.normal(size=(p, n)),
            rng.normal(size=n), rng.normal(size=(p, n)))


def _reference(Phi, Psi, v, dv, c, dc, count):
    x, dx = v.copy(), dv.copy()
    o, op = np.empty(count), np.empty((len(dv), count))
    for k in range(count):
        o[k] = c @ x
        op[:, k] = dc @ x + dx @ c
        x, dx = Phi @ x, np.einsum("pij,j->pi", Psi, x) + dx @ Phi.T
    return o, op


@pytest.mark.parametrize("count", [0, 1, 2, 3, 4, 5, 7, 8, 9, 31, 33, 64, 100, 257, 1000])
@pytest.mark.parametrize("n,p", [(1, 1), (6, 3), (20, 4)])
def test_projected_outputs_match_step_by_step(count, n, p):
    Phi, Psi, v, dv, c, dc = _system(n, p, count + 7 * n)
    o_ref, op_ref = _reference(Phi, Psi, v, dv, c, dc, count)
    o, op = doubling.krylov_sensitivity_outputs(Phi, Psi, v, dv, c, dc, count)
    scale = max(np.abs(o_ref).max(initial=0.0), 1e-300)
    assert o.shape == (count,) and op.shape == (p, count)
    assert np.abs(o - o_ref).max(initial=0.0) <= 1e-12 * scale
    assert np.abs(op - op_ref).max(initial=0.0) <= 1e-12 * max(np.abs(op_ref).max(initial=0.0), 1e-300)
    np.testing.assert_allclose(doubling.krylov_outputs(Phi, v, c, count), o, rtol=0, atol=1e-13 * scale)


def test_lag_split_covers_every_lag_once():
    for count in range(0, 600):
        K, A = doubling.split_lags(count)
        assert K & (K - 1) == 0 and K * K <= max(count, 1) and A == -(-count // K)
        assert (A - 1) * K < count <= A * K or count == 0


@pytest.mark.parametrize("count", [1, 2, 5, 8, 33])
def test_power_rows_match_repeated_products(count):
    Phi, Psi, v, dv, _, _ = _system(5, 2, count)
    X, dX, Mt, dMt = doubling.power_rows(v, dv, Phi, Psi, count)
    x, dx = v.copy(), dv.copy()
    for k in range(count):
        np.testing.assert_allclose(X[k], x, rtol=0, atol=1e-13)
        np.testing.assert_allclose(dX[:, k], dx, rtol=0, atol=1e-13)
        x, dx = x @ Phi, dx @ Phi + np.einsum("j,pjk->pk", x, Psi)
    T = 1 << (count - 1).bit_length()
    P, Q = np.eye(5), np.zeros_like(Psi)
    for _ in range(T):
        P, Q = P @ Phi, Q @ Phi + P @ Psi
    np.testing.assert_allclose(Mt, P, rtol=0, atol=1e-13)
    np.testing.assert_allclose(dMt, Q, rtol=0, atol=1e-13)
    X2, dX2, none, none2 = doubling.power_rows(v, dv, Phi, Psi, count, power=False)
    assert np.array_equal(X2, X) and np.array_equal(dX2, dX) and none is None and none2 is None
