"""Chapter 7 analyses on (inputs, mean sensory score) pairs: leave-one-out prediction,
network-structure comparison, sensitivities (eq. 7.2) and the linear baseline.

* :func:`leave_one_out`: each sample in turn is the test sample; a fresh clone of the
  estimator is fitted on the others (the network then splits those into training and
  validation samples itself, Section 7.2.5) and predicts the held-out one. Fold k gets the
  seed ``SeedSequence(seed).spawn(n)[k]``, so a result is reproducible and independent of
  the order in which folds run.
* Above ``LOO_MAX`` samples, leave-one-out (n network fits) is replaced by seeded
  ``KFOLD``-fold cross-validation (:func:`validation_for`, :func:`cross_validate`); the
  validation used is named in the output. Above ``STRUCTURE_SUBSET`` samples the structures
  are compared on a seeded random subset of that many samples (the chosen network itself is
  validated on all of them).
* :func:`structure_comparison`: leave-one-out (or K-fold) MSE of several hidden-layer structures
  (Fig. 7.2), and the smallest one within one standard error of the best.
* :func:`sensitivities`: eq. 7.2 as in Table 7.4, the mean and SD over samples of
  |f(x with input j times 1.1) - f(x)|.
* :func:`ridge_baseline`: min-max scaling + ridge regression, the penalty chosen by
  (efficient) leave-one-out on the training samples only.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import pandas as pd
from sklearn.base import clone
from sklearn.model_selection import LeaveOneOut

from mbus_framework.analysis.crispness.regressor import LMNetworkRegressor

#: structures compared by default: one hidden layer of 2..10 neurons, two layers of 3 (Fig. 7.2)
DEFAULT_STRUCTURES: tuple[tuple[int, ...], ...] = ((2,), (3,), (4,), (5,), (6,), (8,), (10,), (3, 3))


def ridge_baseline():
    """Linear baseline: [0, 1] scaling + RidgeCV over 1e-4..1e3 (penalty by LOO on training data)."""
    from sklearn.linear_model import RidgeCV
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import MinMaxScaler

    return make_pipeline(MinMaxScaler(), RidgeCV(alphas=np.logspace(-4, 3, 29)))


#: leave-one-out up to this many samples; K-fold cross-validation above
LOO_MAX = 200
#: folds of the K-fold cross-validation used above LOO_MAX
KFOLD = 5
#: above this many samples, the structure comparison runs on a seeded subset of this size
STRUCTURE_SUBSET = 2000


def validation_for(n: int, loo_max: int | None = None, folds: int | None = None) -> tuple[str, int | None]:
    """(name, folds) of the validation used for n samples: ('leave-one-out', None) up to
    ``loo_max`` (default ``LOO_MAX``), else ('5-fold cross-validation', 5) (``KFOLD``)."""
    loo_max = LOO_MAX if loo_max is None else loo_max
    folds = KFOLD if folds is None else folds
    if n <= loo_max:
        return "leave-one-out", None
    return f"{folds}-fold cross-validation", folds


def fold_seeds(seed: int | None, n: int) -> list[int]:
    """Independent 32-bit seeds of n folds from one seed."""
    return [int(s.generate_state(1)[0]) for s in np.random.SeedSequence(seed).spawn(n)]


@dataclass
class LooResult:
    predictions: np.ndarray
    fold_models: list | None = None  # kept only when asked (keep_models=True)

    def squared_errors(self, y) -> np.ndarray:
        return (self.predictions - np.asarray(y, dtype=float)) ** 2


def leave_one_out(estimator, X, y, seed: int | None = 0, progress=None, description: str = "leave-one-out", keep_models: bool = False) -> LooResult:
    """Leave-one-out predictions of ``estimator`` (see the module docstring)."""
    return cross_validate(estimator, X, y, seed, progress, description, keep_models, folds=None)


def _fit_fold(estimator, X, y, train, test, seed):
    est = clone(estimator)
    if seed is not None:
        est.set_params(random_state=seed)
    est.fit(X[train], y[train])
    return test, est.predict(X[test]), est


def cross_validate(estimator, X, y, seed: int | None = 0, progress=None, description: str = "leave-one-out",
                   keep_models: bool = False, folds: int | None = None, n_jobs: int | None = None) -> LooResult:
    """Out-of-fold predictions of ``estimator``: leave-one-out when ``folds`` is None, else
    ``folds``-fold with the samples shuffled by ``seed``; fold k's estimator gets seed
    ``fold_seeds(seed, n_folds)[k]``. K-fold folds run in ``n_jobs`` processes (default: one per
    CPU, at most ``folds``); the result does not depend on it."""
    from sklearn.model_selection import KFold

    X, y = np.asarray(X, dtype=float), np.asarray(y, dtype=float)
    n = len(y)
    splitter = LeaveOneOut() if folds is None else KFold(n_splits=folds, shuffle=True, random_state=fold_seeds(seed, 1)[0])
    n_folds = n if folds is None else folds
    seeded = "random_state" in estimator.get_params()
    seeds = fold_seeds(seed, n_folds) if seeded else [None] * n_folds
    if n_jobs is None:
        n_jobs = 1 if folds is None else min(folds, os.cpu_count() or 1)
    pred = np.empty(n)
    models = [] if keep_models else None
    jobs = [(train, test, seeds[k]) for k, (train, test) in enumerate(splitter.split(X))]
    if progress is not None:
        progress.start(description, total=n_folds)
    try:
        if n_jobs > 1:
            from joblib import Parallel, delayed

            results = Parallel(n_jobs=n_jobs, return_as="generator")(
                delayed(_fit_fold)(estimator, X, y, tr, te, sd) for tr, te, sd in jobs)
        else:
            results = (_fit_fold(estimator, X, y, tr, te, sd) for tr, te, sd in jobs)
        for test, p, est in results:  # in fold order
            pred[test] = p
            if models is not None:
                models.append(est)
            if progress is not None:
                progress.advance(1)
    finally:
        if progress is not None:
            progress.stop()
    return LooResult(pred, models)


def structure_label(hidden: Sequence[int]) -> str:
    return "-".join(str(int(h)) for h in hidden)


def structure_comparison(
    X, y, structures: Sequence[Sequence[int]] = DEFAULT_STRUCTURES, base: LMNetworkRegressor | None = None,
    seed: int | None = 0, progress=None, folds: int | None = None,
) -> tuple[pd.DataFrame, dict[str, dict]]:
    """Leave-one-out (``folds`` None) or K-fold MSE per hidden-layer structure, and each
    structure's learning curves (training and validation MSE per epoch) from one fit on all samples.

    Returns (table with columns structure, layers, neurons, weights, loo_mse, loo_mse_se,
    loo_r, recommended; {structure: learning curves}).
    """
    base = base or LMNetworkRegressor()
    X, y = np.asarray(X, dtype=float), np.asarray(y, dtype=float)
    rows, curves = [], {}
    for i, hidden in enumerate(structures):
        est = clone(base).set_params(hidden_layer_sizes=tuple(hidden))
        label = structure_label(hidden)
        loo = cross_validate(est, X, y, seed, progress, f"structure {label}", folds=folds)
        se = loo.squared_errors(y)
        full = clone(est).set_params(random_state=fold_seeds(seed, 1)[0]).fit(X, y)
        curves[label] = full.learning_curves()[0]
        rows.append({
            "structure": label, "layers": len(hidden), "neurons": int(sum(hidden)), "weights": full.net_.n_weights,
            "loo_mse": float(se.mean()), "loo_mse_se": float(se.std(ddof=1) / np.sqrt(len(se))),
            "loo_r": float(np.corrcoef(loo.predictions, y)[0, 1]),
        })
    table = pd.DataFrame(rows)
    table["recommended"] = False
    table.loc[recommend_structure(table), "recommended"] = True
    return table, curves


def recommend_structure(table: pd.DataFrame) -> int:
    """Index of the smallest network (fewest layers, then weights) whose leave-one-out MSE is
    within one standard error of the best ('the smallest number of inner layers and neurons
    that still give small errors', Section 7.3.2)."""
    best = table["loo_mse"].idxmin()
    limit = table.loc[best, "loo_mse"] + table.loc[best, "loo_mse_se"]
    ok = table[table["loo_mse"] <= limit]
    return int(ok.sort_values(["layers", "weights", "loo_mse"]).index[0])


def sensitivities(predict: Callable[[np.ndarray], np.ndarray], X, names: Sequence[str], relative_change: float = 0.1) -> pd.DataFrame:
    """Eq. 7.2 / Table 7.4: per input j, the mean and SD over samples of
    |f(x_1, .., x_j (1 + c), .., x_d) - f(x)| (c = ``relative_change``), and the signed mean."""
    X = np.asarray(X, dtype=float)
    base = np.asarray(predict(X), dtype=float)
    rows = []
    for j, name in enumerate(names):
        moved = X.copy()
        moved[:, j] *= 1.0 + relative_change
        d = np.asarray(predict(moved), dtype=float) - base
        rows.append({"input": name, "mean_abs_change": float(np.mean(np.abs(d))),
                     "sd_abs_change": float(np.std(np.abs(d), ddof=1)) if d.size > 1 else 0.0,
                     "mean_change": float(np.mean(d))})
    return pd.DataFrame(rows).set_index("input")


def rank(sens: pd.DataFrame) -> list[str]:
    """Inputs by decreasing mean |change|."""
    return list(sens.sort_values("mean_abs_change", ascending=False).index)
