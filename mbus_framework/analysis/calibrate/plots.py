"""Figs 6.4-6.7: MBUS against conventional values, fit lines, confidence and prediction bands.

One figure per property, one panel per MBUS variant (before and after compensation differ by
orders of magnitude, so each gets its own axis): the samples, the least-squares line, its
confidence band (the mean line) and the prediction band (a new sample), at the analysis level.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mbus_framework.analysis.calibrate.model import CONVENTIONAL_LABEL, FIGURES, CalibrationAnalysis
from mbus_framework.analysis.conventional.sheet import PREFIX
from mbus_framework.analysis.rows import usable_rows

UNITS = {"E_sigma": "Pa", "eta_sigma": "Pa s", "E_tau": "Pa", "eta_tau": "Pa s"}


def plot_property(analysis: CalibrationAnalysis, prop: str, path: Path) -> Path:
    """Write the figure of one property (PNG) and return its path."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    variants = [v for v in analysis.variants if (v, prop) in analysis.fits]
    fig, axes = plt.subplots(1, len(variants), figsize=(4.6 * len(variants), 3.8), squeeze=False)
    unit = UNITS.get(prop, "")
    styles = ["-", "--", "-.", ":"]
    pct = int(round(100 * analysis.level))
    for i, (ax, variant) in enumerate(zip(axes.flat, variants)):
        fit = analysis.fits[(variant, prop)]
        used, _ = usable_rows(analysis.rows[variant], [prop, PREFIX + prop])
        x, y = used[PREFIX + prop].to_numpy(float), used[prop].to_numpy(float)
        pad = 0.05 * (fit.x_max - fit.x_min)
        grid = np.linspace(fit.x_min - pad, fit.x_max + pad, 200)
        band = fit.bands(grid)
        ax.fill_between(grid, band["pi_low"], band["pi_high"], color="C0", alpha=0.12,
                        label=f"{pct} % prediction band")
        ax.fill_between(grid, band["ci_low"], band["ci_high"], color="C0", alpha=0.3,
                        label=f"{pct} % confidence band")
        ax.plot(grid, band["mean"], styles[i % len(styles)], color="k", lw=1.3,
                label=f"y = {fit.intercept:.3g} + {fit.slope:.3g} x, r = {fit.r:.3f}")
        ax.plot(x, y, "o", ms=4, color="C3", label=f"samples (N = {fit.n})")
        ax.set_xlabel(f"conventional ({CONVENTIONAL_LABEL.get(prop, prop)}) [{unit}]")
        ax.set_ylabel(f"MBUS {prop} [{unit}]")
        ax.set_title(f"{variant}", fontsize=9)
        ax.ticklabel_format(style="sci", scilimits=(-2, 3))
        ax.legend(fontsize=6.5, loc="upper left")
    fig.suptitle(f"Fig. {FIGURES.get(prop, '')}: {prop}, MBUS against conventional", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_all(analysis: CalibrationAnalysis, out_dir: Path) -> dict[str, Path]:
    """One figure per property: ``fig_6_4_E_sigma.png`` ... (Figs 6.4-6.7)."""
    out = {}
    for prop in analysis.properties:
        number = FIGURES.get(prop, "x").replace(".", "_")
        out[prop] = plot_property(analysis, prop, out_dir / f"fig_{number}_{prop}.png")
    return out
