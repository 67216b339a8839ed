"""Arithmetic-only array helpers, so one model definition serves every evaluator.

A medium model builds its state-space matrices with ``+ - * /`` and ``@`` on arrays made
by :func:`zeros_like_params`. The same code then runs on

* ``float64`` parameters: the fast numeric simulator;
* ``complex128`` parameters: complex-step derivatives dA/dtheta (exact to round-off);
* an object array of CasADi ``SX`` scalars: symbolic evaluation for collocation solvers.

Model code must therefore avoid ``np.linalg``, ``abs``, comparisons on parameter values
and anything else that is not analytic arithmetic.
"""
from __future__ import annotations

import numpy as np


def array_dtype(params) -> np.dtype:
    """dtype an evaluation over ``params`` must use: float64, complex128 or object."""
    arr = np.asarray(params)
    if arr.dtype == object:
        return np.dtype(object)
    if np.iscomplexobj(arr):
        return np.dtype(np.complex128)
    return np.dtype(np.float64)


def zeros_like_params(shape, params) -> np.ndarray:
    """Zero array of ``shape`` able to hold values computed from ``params``."""
    dtype = array_dtype(params)
    out = np.zeros(shape, dtype=dtype)
    if dtype == object:
        out[...] = 0.0
    return out


def to_casadi(matrix):
    """Convert an object array of CasADi scalars (or numbers) to a CasADi ``SX`` matrix."""
    import casadi as ca

    arr = np.atleast_2d(np.asarray(matrix, dtype=object))
    rows = [ca.horzcat(*[ca.SX(v) if not isinstance(v, ca.SX) else v for v in row]) for row in arr]
    return ca.vertcat(*rows)
