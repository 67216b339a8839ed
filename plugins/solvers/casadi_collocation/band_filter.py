"""The strategy's band-limited stages as a causal Butterworth filter in state-space form (its states join the NLP)."""
from __future__ import annotations

import numpy as np


# ---------------------------------------------------------------------------------------------
# band filter as a causal state-space system
# ---------------------------------------------------------------------------------------------
def butterworth_ss(cutoff_hz: float, dt: float, order: int = 4):
    """Discrete Butterworth low-pass (bilinear), |H| = 1/sqrt(1 + (f/fc)^(2 order)), as (Af, Bf, Cf, Df).

    Built as a cascade of second-order sections, each in transposed direct form II
    (z1' = -a1 z1 + z2 + (b1 - a1 b0) x, z2' = -a2 z1 + (b2 - a2 b0) x, y = z1 + b0 x).
    """
    from scipy import signal

    wn = min(cutoff_hz / (0.5 / dt), 0.999)
    sos = signal.butter(order, wn, output="sos")
    A = np.zeros((0, 0))
    B, C, D = np.zeros(0), np.zeros(0), 1.0
    for b0, b1, b2, _, a1, a2 in sos:
        As = np.array([[-a1, 1.0], [-a2, 0.0]])
        Bs = np.array([b1 - a1 * b0, b2 - a2 * b0])
        Cs = np.array([1.0, 0.0])
        k = A.shape[0]
        # cascade: this section is driven by the previous output C z + D x
        An = np.zeros((k + 2, k + 2))
        An[:k, :k] = A
        An[k:, :k] = np.outer(Bs, C)
        An[k:, k:] = As
        B = np.concatenate([B, Bs * D])
        C = np.concatenate([b0 * C, Cs])
        D = b0 * D
        A = An
    return A, B, C, float(D)


def filter_states(Af, Bf, x):
    """States z_k of z_k+1 = Af z_k + Bf x_k from rest, (nf, N)."""
    N = x.size
    Z = np.zeros((Af.shape[0], N))
    for k in range(N - 1):
        Z[:, k + 1] = Af @ Z[:, k] + Bf * x[k]
    return Z


def filter_data(Af, Bf, Cf, Df, x):
    """Output of the discrete filter (Af, Bf, Cf, Df) driven by ``x`` from rest."""
    return Cf @ filter_states(Af, Bf, x) + Df * x
