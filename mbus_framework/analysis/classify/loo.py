"""Leave-one-out predictions of an equal-prior LDA in closed form (no refits).

With equal priors, LDA assigns x to the group k that minimises the Mahalanobis distance
(x - m_k)' W^-1 (x - m_k), W the pooled within-group scatter matrix (its scale does not change
the argmin). Leaving sample i of group c out changes only m_c and W:

    m_c' = m_c - d / (n_c - 1),    W' = W - a d d',   d = x_i - m_c,   a = n_c / (n_c - 1)

so x_i - m_c' = a d, and by Sherman-Morrison, with h = d' W^-1 d,

    W'^-1 = W^-1 + a W^-1 d d' W^-1 / (1 - a h).

Every distance is then (e' W^-1 e) + a (e' W^-1 d)^2 / (1 - a h) for e = x_i - m_k' : one
O(n k p^2) array expression instead of n refits. It equals scikit-learn's
``LinearDiscriminantAnalysis(priors=equal)`` under ``LeaveOneOut`` whenever W' is well
conditioned (tests/test_classify_scaling.py checks it against the brute force); when it is not
(a constant or collinear feature, a group that leaves a singular W'), :func:`closed_form_loo`
returns ``None`` and the caller refits (scikit-learn's SVD solver handles rank deficiency).
"""
from __future__ import annotations

import numpy as np

#: condition number of W (after scaling each feature) above which the closed form is not trusted
MAX_CONDITION = 1e8


def closed_form_loo(X: np.ndarray, labels: np.ndarray, k: int) -> np.ndarray | None:
    """Group index predicted for each left-out row, or ``None`` when W (or some W') is near singular."""
    X = np.asarray(X, dtype=float)
    labels = np.asarray(labels, dtype=int)
    n, p = X.shape
    sizes = np.bincount(labels, minlength=k).astype(float)
    if np.any(sizes < 2) or n - k < p:
        return None
    means = np.zeros((k, p))
    np.add.at(means, labels, X)
    means /= sizes[:, None]
    D = X - means[labels]  # d_i = x_i - m_c
    scale = np.sqrt(np.mean(D * D, axis=0))
    if np.any(scale <= 0):
        return None
    D, Xs, Ms = D / scale, X / scale, means / scale  # unit within-group spread: conditioning is meaningful
    W = D.T @ D
    if np.linalg.cond(W) > MAX_CONDITION:
        return None
    Winv = np.linalg.inv(W)
    a = sizes[labels] / (sizes[labels] - 1.0)  # (n,)
    WD = D @ Winv  # rows: W^-1 d_i
    h = np.einsum("ij,ij->i", WD, D)
    denom = 1.0 - a * h
    if np.any(denom <= 1.0 / MAX_CONDITION):  # leaving the sample out makes W' (near) singular
        return None
    E = Xs[:, None, :] - Ms[None, :, :]  # (n, k, p): x_i - m_k
    own = np.arange(n), labels
    E[own] = a[:, None] * D  # x_i - m_c' for the sample's own group
    quad = np.einsum("nkp,pq,nkq->nk", E, Winv, E)
    proj = np.einsum("nkp,np->nk", E, WD)
    dist = quad + a[:, None] * proj**2 / denom[:, None]
    return np.argmin(dist, axis=1)
