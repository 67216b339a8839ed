"""The doubling path's projected outputs against a plain step-by-step recursion.

``krylov_outputs`` and ``krylov_sensitivity_outputs`` (:mod:`mbus_framework.engine.doubling`)
form only the states a later doubling level reads and project the rest; the reference here
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


def test_schedule_reads_only_formed_states():
    for count in range(1, 600):
        levels, need = doubling.doubling_schedule(count)
        assert sum(t for _, t in levels) + 1 == count
        assert all(t <= f for f, t in levels) and need <= max(1, -(-count // 2))
