"""Every property by group: the rows' estimates with their 95 % intervals, the group mean with
+-1 SD between the rows, and the mean truth of simulated samples."""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from mbus_framework.campaigns.summary import group_labels
from mbus_framework.studies.common import _pyplot, _save_figure


def property_plots(df, summary, groups: Sequence[str], quantities: Sequence[str], out_dir: str | Path,
                   title: str = "", units: Mapping[str, str] | None = None) -> dict[str, Path]:
    """One PNG per quantity, ``<out_dir>/<quantity>_by_group.png``, its axis in a scaled unit of
    ``units[quantity]`` (e.g. GPa; "recorded units" when unknown); returns quantity -> path."""
    import pandas as pd

    from mbus_framework.pipeline.figures import wrapped
    from mbus_framework.pipeline.units import UNKNOWN, label_axis

    units = units or {}
    plt = _pyplot()
    out = Path(out_dir)
    labels = np.array(group_labels(df, groups), dtype=object)
    ok = df["error"].isna().to_numpy() if "error" in df else np.ones(len(df), bool)
    order = list(dict.fromkeys(group_labels(summary, groups)))
    x_of = {g: i for i, g in enumerate(order)}
    paths: dict[str, Path] = {}
    for q in quantities:
        fig, ax = plt.subplots(figsize=(max(4.0, 0.9 * len(order) + 2.0), 3.6))
        values = pd.to_numeric(df[q], errors="coerce").to_numpy(float)
        k = label_axis(ax, "y", q, values[ok], units.get(q.removeprefix("true_"), UNKNOWN))
        values = values / k
        lo = pd.to_numeric(df.get(f"{q}_ci_low"), errors="coerce") / k if f"{q}_ci_low" in df else None
        hi = pd.to_numeric(df.get(f"{q}_ci_high"), errors="coerce") / k if f"{q}_ci_high" in df else None
        label = "each fit, 95 % interval"
        for g in order:
            rows = np.flatnonzero((labels == g) & ok & np.isfinite(values))
            if not rows.size:
                continue
            x = x_of[g] + np.linspace(-0.18, 0.18, rows.size) if rows.size > 1 else np.array([float(x_of[g])])
            v = values[rows]
            if lo is not None and hi is not None:
                err = np.vstack([v - lo.to_numpy(float)[rows], hi.to_numpy(float)[rows] - v])
                err = np.where(np.isfinite(err), np.clip(err, 0, None), 0.0)
                ax.errorbar(x, v, yerr=err, fmt="o", ms=3, color="tab:blue", alpha=0.6, elinewidth=0.8, capsize=1.5,
                            label=label)
            else:
                ax.plot(x, v, "o", ms=3, color="tab:blue", alpha=0.6, label=label)
            label = None
        s = summary.set_index(np.array(group_labels(summary, groups), dtype=object))
        xs = [x_of[g] for g in order]
        ax.errorbar(np.array(xs) + 0.32, s.loc[order, f"{q}_mean"] / k, yerr=s.loc[order, f"{q}_sd"].fillna(0.0) / k,
                    fmt="s", color="k", ms=5, capsize=3, label="group mean ± 1 SD")
        if f"{q}_true_mean" in s:
            ax.plot(np.array(xs) + 0.32, s.loc[order, f"{q}_true_mean"] / k, "x", color="tab:red", ms=8, label="mean truth")
        ax.set_xlabel("group (" + ", ".join(groups) + ")" if groups else "group (all rows)")
        ax.set_xticks(xs, order, rotation=30 if len(order) > 4 else 0, ha="right" if len(order) > 4 else "center")
        ax.set_title(wrapped(fig, f"{title}: {q} by group" if title else f"{q} by group", 10), fontsize=10)
        ax.legend(fontsize=7)
        ax.grid(axis="y", alpha=0.3)
        fig.tight_layout()
        paths[q] = _save_figure(fig, out / f"{q}_by_group.png")
    return paths
