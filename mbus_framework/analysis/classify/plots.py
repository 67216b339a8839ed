"""Discriminant-space plots of a classification: one panel per property set.

Each panel shows the samples in the space of the linear discriminants fitted on all samples
(LD1 vs LD2 when there are two or more, with each group's 95 % ellipse: mean +- the
chi-square(2) 95 % contour of its covariance), or along LD1 by group when there is one.
Large tables: the discriminants and ellipses use every sample, but at most ``MAX_POINTS``
samples are drawn (a seeded random subset, each group keeping its share, at least one
sample), and the figure says so.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mbus_framework.analysis.classify.model import Classification, set_label

#: at most this many samples are drawn per panel (all are used for the discriminants and ellipses)
MAX_POINTS = 2000


def drawn_samples(labels: np.ndarray, max_points: int = MAX_POINTS, seed: int = 0) -> np.ndarray:
    """Boolean mask of the samples to draw: all when few, else a seeded subset of about
    ``max_points`` with each group kept in proportion (at least one sample per group)."""
    labels = np.asarray(labels)
    n = labels.size
    if n <= max_points:
        return np.ones(n, dtype=bool)
    rng = np.random.default_rng(seed)
    mask = np.zeros(n, dtype=bool)
    for g in np.unique(labels):
        idx = np.flatnonzero(labels == g)
        take = max(1, int(round(max_points * idx.size / n)))
        mask[rng.choice(idx, size=min(take, idx.size), replace=False)] = True
    return mask


def discriminant_scores(X: np.ndarray, labels: np.ndarray, k: int) -> np.ndarray:
    """Scores of the samples on the (at most two) leading discriminants (equal priors)."""
    from sklearn.discriminant_analysis import LinearDiscriminantAnalysis

    lda = LinearDiscriminantAnalysis(priors=np.full(k, 1.0 / k))
    scores = lda.fit(X, labels).transform(X)
    return scores[:, :2]


def ellipse_axes(points: np.ndarray, level: float = 0.95):
    """(centre, width, height, angle in degrees) of the ``level`` ellipse of 2-D points."""
    from scipy import stats

    centre = points.mean(axis=0)
    vals, vecs = np.linalg.eigh(np.cov(points, rowvar=False))
    q = stats.chi2.ppf(level, 2)
    width, height = 2.0 * np.sqrt(q * np.clip(vals[::-1], 0.0, None))
    angle = math.degrees(math.atan2(vecs[1, -1], vecs[0, -1]))
    return centre, width, height, angle


def plot_discriminant_space(result: Classification, path: Path) -> Path:
    """Write the figure (PNG) and return its path."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.patches import Ellipse

    sets = list(result.features)
    k = len(result.groups)
    ncols = min(4, len(sets))
    nrows = math.ceil(len(sets) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.6 * ncols, 3.3 * nrows), squeeze=False)
    colours = plt.get_cmap("tab10" if k <= 10 else "tab20")
    lda_pct = {f: r.percent_correct for f, r in result.results["lda"].items()}
    drawn = drawn_samples(result.labels)
    for ax, feats in zip(axes.flat, sets):
        scores = discriminant_scores(result.features[feats], result.labels, k)
        size = 18 if drawn.all() else 4
        for g, group in enumerate(result.groups):
            everyone = scores[result.labels == g]
            pts = scores[(result.labels == g) & drawn]
            colour = colours(g % colours.N)
            if scores.shape[1] >= 2:
                ax.scatter(pts[:, 0], pts[:, 1], s=size, color=colour, label=group)
                if len(everyone) >= 3:
                    centre, w, h, angle = ellipse_axes(everyone[:, :2])
                    ax.add_patch(Ellipse(centre, w, h, angle=angle, fill=False, color=colour, lw=1.2))
            else:
                step = min(0.04, 0.6 / max(len(pts) - 1, 1))  # the group's row stays within +-0.3
                jitter = (np.arange(len(pts)) - (len(pts) - 1) / 2) * step
                ax.scatter(pts[:, 0], g + jitter, s=size, color=colour, label=group)
        if scores.shape[1] >= 2:
            ax.set_xlabel("LD1")
            ax.set_ylabel("LD2")
            ax.autoscale_view()
        else:
            ax.set_yticks(range(k), result.groups, fontsize=7)
            ax.set_xlabel("LD1")
        ax.set_title(f"{set_label(feats)}\nLDA-LOO {lda_pct[feats]:.0f} %", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(sets):]:
        ax.set_visible(False)
    handles, names = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="lower center", ncol=min(k, 6), fontsize=8, frameon=False)
    title = f"Discriminant space by {result.by}"
    if not drawn.all():
        title += f" ({int(drawn.sum()):,} of {drawn.size:,} samples drawn; ellipses from all)"
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.06, 1, 0.97))
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
