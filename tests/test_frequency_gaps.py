"""The eigenvalue gaps shared by the parameters of one frequency-response Jacobian give
exactly the per-parameter divided-difference term, including nearly equal eigenvalues."""
from __future__ import annotations

import numpy as np

from mbus_framework.engine import frequency as fr


def test_shared_gaps_equal_per_parameter_gaps():
    rng = np.random.default_rng(3)
    dt = 1.6e-7
    lam = np.concatenate([-rng.uniform(1e3, 1e5, 6) + 1j * rng.uniform(1e5, 1e7, 6), [-2e4 + 3e6j]])
    lam = np.append(lam, lam[-1] * (1 + 1e-9))  # a nearly equal pair: the derivative is used
    f = np.linspace(1e4, 2e6, 40)
    val, der = fr._point_values(lam, f, dt)
    gaps = fr._gaps(lam, dt)
    assert gaps[1].sum() > lam.size  # the pair counts as close
    for _ in range(3):
        q = rng.normal(size=(lam.size, lam.size)) + 1j * rng.normal(size=(lam.size, lam.size))
        np.testing.assert_array_equal(fr._fdk_term(lam, val, der, q, dt, gaps), fr._fdk_term(lam, val, der, q, dt))
    # against the divided differences written out
    q = rng.normal(size=(lam.size, lam.size))
    ref = np.zeros(f.size, dtype=complex)
    for i in range(lam.size):
        for j in range(lam.size):
            if gaps[1][i, j]:
                ref += q[i, j] * 0.5 * (der[:, i] + der[:, j])
            else:
                ref += q[i, j] * (val[:, i] - val[:, j]) / (lam[i] - lam[j])
    np.testing.assert_allclose(fr._fdk_term(lam, val, der, q, dt, gaps), ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
