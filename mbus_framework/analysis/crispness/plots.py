"""Figures of the crispness analysis (matplotlib, Agg): measured vs predicted (Figs 7.3/7.4)
for the network and the ridge baseline side by side, the structure comparison (Fig. 7.2),
the sensitivities (Table 7.4) and the panel's scores by assessor and group."""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from mbus_framework.analysis.crispness.agreement import Agreement
from mbus_framework.studies.common import _pyplot, _save_figure as _save  # Agg backend; atomic PNG


def measured_vs_predicted(rows: Sequence[tuple[str, Sequence[tuple[str, np.ndarray, np.ndarray, Agreement]]]], path: Path, score_range=(0.0, 9.0)) -> Path:
    """One row of panels per input set, one panel per predictor (network, ridge):
    predicted against measured score with the 1:1 line, the fitted line and its statistics."""
    plt = _pyplot()
    n_rows, n_cols = len(rows), max(len(r[1]) for r in rows)
    fig, axes = plt.subplots(n_rows, n_cols, figsize=(4.6 * n_cols, 4.4 * n_rows), squeeze=False)
    lo, hi = score_range
    for i, (row_title, panels) in enumerate(rows):
        for j, (name, measured, predicted, a) in enumerate(panels):
            ax = axes[i, j]
            ax.plot([lo, hi], [lo, hi], color="0.6", ls="--", lw=1, label="1:1")
            ax.scatter(measured, predicted, s=22, color="C0" if j == 0 else "C1", edgecolor="k", lw=0.4, zorder=3)
            xs = np.array([lo, hi])
            ax.plot(xs, a.intercept + a.slope * xs, color="k", lw=1.2, label="fitted line")
            ax.set_xlim(lo, hi)
            ax.set_ylim(lo, hi)
            ax.set_aspect("equal")
            ax.set_xlabel("sensory score (panel mean)")
            ax.set_ylabel("predicted score (leave-one-out)")
            ax.set_title(f"{name}\n{row_title}", fontsize=9)
            text = (f"r = {a.r:.4f}  (n = {a.n})\ny = {a.intercept:.3f} + {a.slope:.3f} x\n"
                    f"slope = 1: p = {a.slope_p:.3g}\nintercept = 0: p = {a.intercept_p:.3g}\nRMSE = {a.rmse:.3f}")
            ax.text(0.03, 0.97, text, transform=ax.transAxes, va="top", fontsize=8,
                    bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "0.8"})
            ax.legend(loc="lower right", fontsize=8)
        for j in range(len(panels), n_cols):
            axes[i, j].axis("off")
    fig.tight_layout()
    return _save(fig, path)


def structures(table: pd.DataFrame, curves: Mapping[str, Mapping], path: Path) -> Path:
    """Left: leave-one-out MSE against neurons, one line per number of hidden layers (the
    recommended structure ringed). Right: training (solid) and validation (dashed) MSE per
    epoch of one fit on all samples, per structure (Fig. 7.2)."""
    plt = _pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.3))
    for layers, part in table.groupby("layers"):
        part = part.sort_values("neurons")
        ax1.errorbar(part["neurons"], part["loo_mse"], yerr=part["loo_mse_se"], marker="o", capsize=3,
                     label=f"{layers} hidden layer{'s' if layers > 1 else ''}")
        for _, r in part.iterrows():
            ax1.annotate(r["structure"], (r["neurons"], r["loo_mse"]), textcoords="offset points", xytext=(4, 4), fontsize=7)
    rec = table[table["recommended"]]
    ax1.scatter(rec["neurons"], rec["loo_mse"], s=180, facecolor="none", edgecolor="r", lw=1.5, zorder=4, label="recommended")
    ax1.set_xlabel("neurons in hidden layers")
    ax1.set_ylabel("leave-one-out MSE [score$^2$]")
    ax1.set_title("structure comparison (leave-one-out)", fontsize=10)
    ax1.legend(fontsize=8)
    for k, (label, c) in enumerate(curves.items()):
        color = f"C{k % 10}"
        ax2.semilogy(c["train"], color=color, lw=1.2, label=label)
        if c.get("validation"):
            ax2.semilogy(c["validation"], color=color, lw=1.0, ls="--")
    ax2.set_xlabel("epoch (accepted LM step)")
    ax2.set_ylabel("MSE [score$^2$]")
    ax2.set_title("training (solid) and validation (dashed) MSE", fontsize=10)
    ax2.legend(fontsize=7, ncol=2, title="structure", title_fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def sensitivity_bars(tables: Mapping[str, pd.DataFrame], path: Path, relative_change: float = 0.1) -> Path:
    """Table 7.4 as bars: mean |change of the prediction| for a +10 % change of each input
    (error bars: SD over samples), one group of bars per model."""
    plt = _pyplot()
    names: list[str] = []
    for t in tables.values():
        names += [n for n in t.index if n not in names]
    fig, ax = plt.subplots(figsize=(1.2 + 1.3 * len(names) * max(1, len(tables)) / 2, 4))
    width = 0.8 / max(1, len(tables))
    x = np.arange(len(names))
    for k, (label, t) in enumerate(tables.items()):
        means = [t.loc[n, "mean_abs_change"] if n in t.index else np.nan for n in names]
        sds = [t.loc[n, "sd_abs_change"] if n in t.index else np.nan for n in names]
        ax.bar(x + (k - (len(tables) - 1) / 2) * width, means, width, yerr=sds, capsize=3, label=label)
    ax.set_xticks(x, names)
    ax.set_ylabel(f"|change of predicted score| for +{100 * relative_change:g} %")
    ax.set_title("sensitivities (eq. 7.2, Table 7.4)", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return _save(fig, path)


def panel_scores(panel: pd.DataFrame, group: str | None, path: Path) -> Path:
    """Box plots of the scores by assessor (Table 7.1) and by group (Table 7.2)."""
    plt = _pyplot()
    cols = [c for c in ("assessor", group) if c]
    fig, axes = plt.subplots(1, len(cols), figsize=(5.5 * len(cols), 4), squeeze=False)
    for ax, col in zip(axes[0], cols):
        levels = sorted(panel[col].astype(str).unique())
        data = [panel.loc[panel[col].astype(str) == lv, "score"].to_numpy() for lv in levels]
        ax.boxplot(data)
        ax.set_xticks(range(1, len(levels) + 1), levels, rotation=30, ha="right", fontsize=8)
        ax.set_ylabel("score")
        ax.set_title(f"scores by {col}", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)
