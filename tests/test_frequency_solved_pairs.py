"""The chunked stacked solves of response_batch's direct lines against one solve per pair."""
import numpy as np

from mbus_framework.engine.frequency import _solved_pairs


def test_chunked_pair_solves_equal_one_dense_solve_per_pair():
    rng = np.random.default_rng(3)
    S, n, K = 3, 6, 50
    A = rng.normal(size=(S, n, n))
    B, C = (rng.normal(size=(S, n)) + 0j for _ in range(2))
    which = rng.integers(0, S, K)
    s = 1j * rng.uniform(0.1, 5.0, K)
    ref = np.array([C[w] @ np.linalg.solve(sk * np.eye(n) - A[w], B[w]) for w, sk in zip(which, s)])
    got = _solved_pairs(A, B, C, which, s, chunk=7)  # several chunks, the last one short
    np.testing.assert_allclose(got, ref, rtol=1e-12)
