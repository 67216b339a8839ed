"""Classification of materials from their estimated properties (Chapter 4, Tables 4.4 and 4.5).

For each set of properties (each alone, the normal pair, the shear pair and all four: the
seven columns of Table 4.4, or sets the user names), two methods:

* **k-means** (scikit-learn ``KMeans``, k = number of groups, ``restarts`` seeded starts):
  the clusters are matched one-to-one to the groups so that the most samples agree
  (``scipy.optimize.linear_sum_assignment`` on the group x cluster counts); a sample is
  correctly classified when its cluster is matched to its own group.
* **LDA with leave-one-out**: each sample is predicted by the discriminant fitted on all the
  others, in closed form (:mod:`.loo`, rank-one updates: milliseconds at 10,000 rows). When the
  pooled covariance is near singular, scikit-learn's ``LinearDiscriminantAnalysis`` is refitted
  per fold instead: leave-one-out up to ``REFIT_LOO_MAX`` usable rows, stratified
  ``REFIT_FOLDS``-fold above (the validation used is named in the output).
  Priors are equal (SPSS's default), so a left-out sample's group is not penalised for
  being one sample smaller.

Features are the properties as estimated (default, the dissertation's analysis: on the shipped
tissues campaign LDA leave-one-out with all four properties classifies 93.3 %, Table 4.5), or
log-transformed (``log=True``: they are positive and scatter in proportion to their size), and
standardised (default: k-means distances would otherwise be dominated by the largest property;
LDA does not depend on it). Both are explicit options.

The letters of Tables 4.4/4.5: group j's letter is the j-th letter; each group is given the
letters of the groups its samples were assigned to, so groups sharing a letter are not
separated by that property set.
"""
from __future__ import annotations

import string
import warnings
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from mbus_framework.errors import DataError
from mbus_framework.analysis.rows import usable_rows
from mbus_framework.analysis.table import PROPERTIES, require_columns

#: The seven property sets of Tables 4.4 and 4.5.
DISSERTATION_SETS: tuple[tuple[str, ...], ...] = (
    ("E_sigma",), ("eta_sigma",), ("E_tau",), ("eta_tau",),
    ("E_sigma", "eta_sigma"), ("E_tau", "eta_tau"), PROPERTIES,
)
METHODS = {"kmeans": "K-means clustering", "lda": "Leave-one-out test results by linear discriminant analysis"}
LETTERS = string.ascii_lowercase + string.ascii_uppercase
#: above this many rows, a refitted LDA (closed form not usable) is validated by K-fold, not leave-one-out
REFIT_LOO_MAX = 2000
REFIT_FOLDS = 10
LOO = "leave-one-out"


def feature_sets(properties: Sequence[str]) -> list[tuple[str, ...]]:
    """Each property alone, the dissertation's pairs within ``properties``, then all together."""
    props = tuple(properties)
    sets = [(p,) for p in props]
    for pair in DISSERTATION_SETS[4:6]:
        if set(pair) <= set(props) and len(props) > 2:
            sets.append(pair)
    if len(props) > 1:
        sets.append(props)
    return sets


def set_label(features: Sequence[str]) -> str:
    return ", ".join(features)


def transform(values: np.ndarray, names: Sequence[str], *, log: bool, ids: Sequence[str] = (),
              source: str = "<table>") -> np.ndarray:
    """log10 of the values when ``log`` (positive values required), else the values."""
    values = np.asarray(values, dtype=float)
    if not log:
        return values
    bad = np.argwhere(values <= 0)
    if bad.size:
        row, col = bad[0]
        who = f"sample {ids[row]}" if len(ids) else f"row {row + 1}"
        raise DataError(f"{source}: {names[col]} of {who} is {values[row, col]:.4g}; the log transform needs "
                        "positive values (use --transform none)")
    return np.log10(values)


@dataclass
class MethodResult:
    """One method on one property set: predictions as group indices and their summaries."""

    method: str
    features: tuple[str, ...]
    predicted: np.ndarray
    confusion: np.ndarray
    percent_correct: float
    letters: list[str]
    not_separated: list[tuple[int, int]]
    notes: list[str] = field(default_factory=list)
    validation: str = ""


@dataclass
class Classification:
    """All methods on all property sets for one grouping column."""

    by: str
    groups: list[str]
    labels: np.ndarray
    sample_ids: list[str]
    features: dict[tuple[str, ...], np.ndarray]
    results: dict[str, dict[tuple[str, ...], MethodResult]]
    counts: dict
    log: bool
    standardize: bool
    restarts: int
    seed: int

    def percent_table(self) -> dict[str, dict[str, float]]:
        return {m: {set_label(f): r.percent_correct for f, r in res.items()} for m, res in self.results.items()}


def confusion_matrix(labels: np.ndarray, predicted: np.ndarray, k: int) -> np.ndarray:
    """counts[i, j] = samples of group i assigned to group j."""
    out = np.zeros((k, k), dtype=int)
    np.add.at(out, (labels, predicted), 1)
    return out


def letters_and_pairs(confusion: np.ndarray) -> tuple[list[str], list[tuple[int, int]]]:
    """Each group's letters (the groups it was assigned to) and the pairs not separated."""
    k = confusion.shape[0]
    letters = ["".join(LETTERS[j] for j in range(k) if confusion[i, j] > 0) for i in range(k)]
    pairs = [(i, j) for i in range(k) for j in range(i + 1, k)
             if confusion[i, j] or confusion[j, i] or np.any((confusion[i] > 0) & (confusion[j] > 0))]
    return letters, pairs


def kmeans_predict(X: np.ndarray, labels: np.ndarray, k: int, *, restarts: int = 20, seed: int = 0) -> np.ndarray:
    """k-means clusters mapped to groups by the optimal one-to-one matching."""
    from scipy.optimize import linear_sum_assignment
    from sklearn.cluster import KMeans

    clusters = KMeans(n_clusters=k, n_init=restarts, random_state=seed).fit_predict(X)
    counts = confusion_matrix(labels, clusters, k)  # group x cluster
    groups, matched = linear_sum_assignment(counts, maximize=True)
    to_group = np.empty(k, dtype=int)
    to_group[matched] = groups
    return to_group[clusters]


def lda_validation(n: int, k: int, closed_form: bool) -> str:
    """Name of the validation :func:`lda_loo_predict` uses for n rows."""
    if closed_form or n <= REFIT_LOO_MAX:
        return LOO
    return f"stratified {REFIT_FOLDS}-fold"


def lda_loo_predict(X: np.ndarray, labels: np.ndarray, k: int, seed: int = 0) -> tuple[np.ndarray, str]:
    """Leave-one-out predictions of an equal-prior LDA and the validation's name.

    Closed form when the pooled covariance allows it; else refits (leave-one-out up to
    ``REFIT_LOO_MAX`` rows, stratified ``REFIT_FOLDS``-fold above)."""
    from mbus_framework.analysis.classify.loo import closed_form_loo

    fast = closed_form_loo(X, labels, k)
    if fast is not None:
        return fast, LOO
    from sklearn.discriminant_analysis import LinearDiscriminantAnalysis
    from sklearn.model_selection import LeaveOneOut, StratifiedKFold, cross_val_predict

    lda = LinearDiscriminantAnalysis(priors=np.full(k, 1.0 / k))
    validation = lda_validation(len(labels), k, False)
    if validation == LOO:
        cv = LeaveOneOut()
    else:
        folds = min(REFIT_FOLDS, int(np.bincount(labels).min()))
        validation = f"stratified {folds}-fold"
        cv = StratifiedKFold(n_splits=folds, shuffle=True, random_state=seed)
    return cross_val_predict(lda, X, labels, cv=cv), validation


def _run(method: str, X: np.ndarray, labels: np.ndarray, k: int, restarts: int, seed: int):
    from threadpoolctl import threadpool_limits

    # a few dozen samples: OpenMP/BLAS threads only add start-up cost (and contend on shared machines)
    with threadpool_limits(1), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if method == "kmeans":
            predicted, validation = kmeans_predict(X, labels, k, restarts=restarts, seed=seed), ""
        else:
            predicted, validation = lda_loo_predict(X, labels, k, seed)
    notes = sorted({str(w.message).splitlines()[0] for w in caught if issubclass(w.category, UserWarning)})
    return np.asarray(predicted, dtype=int), notes, validation


def classify(df, by: str, sets: Sequence[Sequence[str]] | None = None, *, log: bool = False,
             standardize: bool = True, restarts: int = 20, seed: int = 0, source: str = "<table>",
             progress=None) -> Classification:
    """Run k-means and LDA leave-one-out on each property set; see the module docstring.

    ``progress``: an optional :class:`~mbus_framework.estimation.problem.Progress`, advanced once
    per property set."""
    if sets is None:
        sets = DISSERTATION_SETS if all(p in df.columns for p in PROPERTIES) else None
        if sets is None:
            raise DataError(f"{source}: not all of {', '.join(PROPERTIES)} are columns; name --properties")
    sets = [tuple(s) for s in sets]
    used = list(dict.fromkeys(p for s in sets for p in s))
    require_columns(df, [by, *used], source)
    rows, counts = usable_rows(df, used)
    unlabelled = int(rows[by].isna().sum())
    rows = rows[rows[by].notna()]
    counts.update(missing=counts["missing"] + unlabelled, used=counts["used"] - unlabelled)
    groups = list(dict.fromkeys(rows[by].astype(str)))
    k = len(groups)
    if k < 2:
        raise DataError(f"{source}: column '{by}' has {k} group(s) among the usable rows; need at least 2")
    if k > len(LETTERS):
        raise DataError(f"{source}: column '{by}' has {k} groups; at most {len(LETTERS)} are supported")
    labels = np.array([groups.index(g) for g in rows[by].astype(str)])
    sizes = np.bincount(labels, minlength=k)
    small = [groups[i] for i in range(k) if sizes[i] < 2]
    if small:
        raise DataError(f"{source}: group(s) {', '.join(small)} of '{by}' have fewer than 2 usable samples; "
                        "leave-one-out needs at least 2 per group")
    ids = rows["sample_id"].astype(str).tolist()
    features: dict[tuple[str, ...], np.ndarray] = {}
    results: dict[str, dict[tuple[str, ...], MethodResult]] = {m: {} for m in METHODS}
    if progress is not None:
        progress.start(f"classify by {by}", total=len(sets))
    try:
        for feats in sets:
            _classify_set(feats, rows, labels, k, ids, features, results, log, standardize, restarts, seed, source)
            if progress is not None:
                progress.advance(1)
    finally:
        if progress is not None:
            progress.stop()
    return Classification(by=by, groups=groups, labels=labels, sample_ids=ids, features=features,
                          results=results, counts=counts, log=log, standardize=standardize,
                          restarts=restarts, seed=seed)


def _classify_set(feats, rows, labels, k, ids, features, results, log, standardize, restarts, seed, source) -> None:
    """Both methods on one property set, stored into ``features`` and ``results``."""
    X = transform(rows[list(feats)].to_numpy(dtype=float), feats, log=log, ids=ids, source=source)
    constant = [f for f, sd in zip(feats, X.std(axis=0)) if not sd > 0]
    if constant:
        value = rows[constant[0]].iloc[0]
        raise DataError(f"{source}: column '{constant[0]}' has the same value ({value:.6g}) in every usable row, so it "
                        "cannot separate groups; leave it out (--properties / --sets)")
    if standardize:
        sd = X.std(axis=0)
        X = (X - X.mean(axis=0)) / np.where(sd > 0, sd, 1.0)
    features[feats] = X
    for method in METHODS:
        predicted, notes, validation = _run(method, X, labels, k, restarts, seed)
        conf = confusion_matrix(labels, predicted, k)
        letters, pairs = letters_and_pairs(conf)
        results[method][feats] = MethodResult(method, feats, predicted, conf,
                                              100.0 * float(np.trace(conf)) / labels.size, letters, pairs, notes,
                                              validation)
