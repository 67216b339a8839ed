"""Group summary in the layout of Tables 4.2/4.3: per group, the mean of each property and its
standard deviation between the group's rows as a percentage of the mean,

    SD% = 100 * sqrt(sum (x_i - mean)^2 / (n - 1)) / |mean|,

over the rows without an error. With simulated samples (``true_<q>`` columns) each group also
gets the mean truth and the error of the mean, 100 * (mean / mean truth - 1).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

ALL = "all"


def group_labels(df, groups: Sequence[str]) -> list[str]:
    """One label per row: the group columns joined by ' / ' (``all`` without groups)."""
    if not groups:
        return [ALL] * len(df)
    return [" / ".join(str(v) for v in values) for values in df[list(groups)].itertuples(index=False)]


def group_summary(df, groups: Sequence[str], quantities: Sequence[str]):
    """DataFrame with one row per group (in order of first appearance): the group columns,
    ``n`` (rows without error), ``n_failed``, and per quantity ``<q>_mean``, ``<q>_sd``,
    ``<q>_sd_percent`` (and ``<q>_true_mean``, ``<q>_error_percent`` when truth is known)."""
    import pandas as pd

    labels = group_labels(df, groups)
    failed = df["error"].notna().to_numpy() if "error" in df else np.zeros(len(df), bool)
    out = []
    for label in dict.fromkeys(labels):
        mask = np.array([lab == label for lab in labels])
        part = df[mask & ~failed]
        first = df[mask].iloc[0]
        row = {g: first[g] for g in groups} if groups else {"group": ALL}
        row.update(n=int(len(part)), n_failed=int((mask & failed).sum()))
        for q in quantities:
            v = pd.to_numeric(part[q], errors="coerce").dropna().to_numpy(float) if q in part else np.array([])
            mean = float(np.mean(v)) if v.size else math.nan
            sd = float(np.std(v, ddof=1)) if v.size > 1 else math.nan
            row[f"{q}_mean"] = mean
            row[f"{q}_sd"] = sd
            row[f"{q}_sd_percent"] = 100.0 * sd / abs(mean) if mean else math.nan
            if f"true_{q}" in part:
                t = pd.to_numeric(part[f"true_{q}"], errors="coerce").dropna().to_numpy(float)
                if t.size:
                    row[f"{q}_true_mean"] = float(np.mean(t))
                    row[f"{q}_error_percent"] = 100.0 * (mean / float(np.mean(t)) - 1.0)
        if "sample_density" in part and part["sample_density"].notna().any():
            densities = part["sample_density"].dropna().unique()
            row["density"] = float(densities[0]) if len(densities) == 1 else math.nan
        out.append(row)
    return pd.DataFrame(out)


def summary_text(summary, groups: Sequence[str], quantities: Sequence[str], title: str) -> str:
    """The summary printed as Tables 4.2/4.3: ``mean (SD%)`` with one power of ten per column."""
    names = list(groups) or ["group"]
    label = [" / ".join(str(r[g]) for g in names) for _, r in summary.iterrows()]
    width = max([len(" / ".join(names)), *map(len, label)]) + 2
    scales = {q: _scale(summary[f"{q}_mean"]) for q in quantities}
    heads = [f"{q} x1e{scales[q]}" if scales[q] else q for q in quantities]
    has_density = "density" in summary and summary["density"].notna().any()
    rows, errors = [], []
    for _, r in summary.iterrows():
        cells = []
        for q in quantities:
            m, sp = r[f"{q}_mean"], r[f"{q}_sd_percent"]
            cells.append((f"{m / 10 ** scales[q]:.3g}" + (f" ({sp:.2f}%)" if sp == sp else "")) if m == m else "-")
        rows.append(cells)
        errors.append([f"{r[f'{q}_error_percent']:+.2f}%" if r.get(f"{q}_error_percent", math.nan) == r.get(
            f"{q}_error_percent", math.nan) else "-" for q in quantities])
    cols = [max(len(heads[k]), *(len(c[k]) for c in rows + errors)) + 3 for k in range(len(quantities))]
    lead = 4 + (10 if has_density else 0)

    def line(start: str, middle: str, cells: list[str], end: str = "") -> str:
        return "  " + start.ljust(width) + middle + "".join(c.rjust(w) for c, w in zip(cells, cols)) + end

    lines = [title, "  mean (SD as % of mean) of each group's fitted rows", ""]
    lines.append(line(" / ".join(names), f"{'n':>4}" + (f"{'density':>10}" if has_density else ""), heads))
    for lab, cells, (_, r) in zip(label, rows, summary.iterrows()):
        density = (f"{r['density']:>10.4g}" if r["density"] == r["density"] else f"{'-':>10}") if has_density else ""
        fails = f"  ({int(r['n_failed'])} failed)" if r["n_failed"] else ""
        lines.append(line(lab, f"{int(r['n']):>4}" + density, cells, fails))
    if any(f"{q}_error_percent" in summary for q in quantities):
        lines += ["", "  error of the group mean against the mean truth (simulated samples)"]
        lines += [line(lab, " " * lead, cells) for lab, cells in zip(label, errors)]
    return "\n".join(lines)


def _scale(values) -> int:
    """The power of ten of the median |value| (0 for values between 0.01 and 1000)."""
    v = np.abs(np.asarray(values, float))
    v = v[np.isfinite(v) & (v > 0)]
    if not v.size:
        return 0
    e = int(math.floor(math.log10(float(np.median(v)))))
    return 0 if -2 <= e <= 2 else e
