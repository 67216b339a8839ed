"""Matrix products kept small enough to stay single-threaded.

The engine's matrices are small (tens of states) but its Krylov and power tables are tall.
"""
from __future__ import annotations

import numpy as np


def small_matmul(a: np.ndarray, b: np.ndarray, rows: int = 128) -> np.ndarray:
    """a @ b for a tall ``a`` (..., M, K), as a stack of small products.

    A tall product with a small inner dimension is exactly the shape a threaded BLAS splits
    across cores; on a shared machine that costs far more than it saves (measured: 25x
    slower with 2 busy cores). Stacking slices of ``rows`` rows keeps every call small and
    single-threaded, whatever the BLAS configuration.
    """
    M = a.shape[-2]
    if M <= rows:
        return a @ b
    m1 = (M // rows) * rows
    lead = a.shape[:-2]
    out = np.empty(np.broadcast_shapes(lead, b.shape[:-2]) + (M, b.shape[-1]), dtype=np.result_type(a, b))
    head = a[..., :m1, :].reshape(lead + (m1 // rows, rows, a.shape[-1]))
    bb = b if b.ndim == 2 else b[..., None, :, :]
    out[..., :m1, :] = (head @ bb).reshape(out.shape[:-2] + (m1, b.shape[-1]))
    if m1 < M:
        out[..., m1:, :] = a[..., m1:, :] @ b
    return out
