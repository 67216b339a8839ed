"""Sensory panel data (Section 7.2.4): reading, joining to the campaign table, statistics.

A panel table is a CSV in long form, one row per score:

    sample_id, assessor, score[, a group column such as cultivar]

``join_scores`` attaches each sample's mean score (over assessors) to the campaign table;
``describe_by`` gives the min/max/mean/std layout of Tables 7.1 (by assessor) and 7.2 (by
group); ``one_way_anova`` the layout of Table 7.3 (SS, df, MS, F, p, F crit), computed with
statsmodels; ``lsd_comparisons`` Fisher's least significant difference between levels
(Section 7.2.6).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from mbus_framework.analysis.table import require_columns
from mbus_framework.errors import DataError

PANEL_COLUMNS = ("sample_id", "assessor", "score")


def read_panel(path: str | Path) -> pd.DataFrame:
    """Read a panel CSV; one-line errors for a missing file, columns, or a non-numeric score."""
    p = Path(path)
    if not p.is_file():
        raise DataError(f"{p}: panel scores not found (expected a CSV with columns {', '.join(PANEL_COLUMNS)})")
    try:
        df = pd.read_csv(p, dtype={"sample_id": str, "assessor": str})
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DataError(f"{p}: cannot read panel scores ({first[:200]})") from None
    require_columns(df, PANEL_COLUMNS, str(p))
    if df.empty:
        raise DataError(f"{p}: no scores")
    return check_panel(df, str(p))


def check_panel(df: pd.DataFrame, source: str = "<panel>") -> pd.DataFrame:
    """Validate a panel frame: ids present, numeric finite scores, one score per (sample, assessor)."""
    require_columns(df, PANEL_COLUMNS, source)
    df = df.copy()
    for col in ("sample_id", "assessor"):
        blank = df[col].isna() | (df[col].astype(str).str.strip() == "")
        if blank.any():
            raise DataError(f"{source}: row {int(np.flatnonzero(blank)[0]) + 2}: empty {col}")
        df[col] = df[col].astype(str).str.strip()
    score = pd.to_numeric(df["score"], errors="coerce")
    bad = score.isna() | ~np.isfinite(score)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise DataError(f"{source}: row {row + 2}, column score: {df['score'].iloc[row]!r} is not a number")
    df["score"] = score.astype(float)
    dup = df.duplicated(["sample_id", "assessor"], keep=False)
    if dup.any():
        rows = np.flatnonzero(dup)[:2] + 2
        first = df.iloc[rows[0] - 2]
        raise DataError(
            f"{source}: rows {rows[0]} and {rows[1]}: assessor {first.assessor!r} scored sample "
            f"{first.sample_id!r} twice (one score per sample and assessor)"
        )
    return df


def attach_group(panel: pd.DataFrame, table: pd.DataFrame, group: str, source: str = "<panel>") -> pd.DataFrame:
    """Give every panel row the ``group`` label: from the panel itself, else from the table."""
    if group in panel.columns:
        return panel
    if group not in table.columns:
        raise DataError(f"{source}: group column {group!r} is in neither the panel nor the table")
    labels = table.drop_duplicates("sample_id").set_index("sample_id")[group]
    out = panel.copy()
    out[group] = out["sample_id"].map(labels)
    return out


def sample_means(panel: pd.DataFrame) -> pd.DataFrame:
    """Per sample: mean score over assessors, its SD and the number of scores."""
    g = panel.groupby("sample_id", sort=False)["score"]
    return pd.DataFrame({"score": g.mean(), "score_sd": g.std(ddof=1), "n_scores": g.size()})


def join_scores(table: pd.DataFrame, panel: pd.DataFrame, inputs, table_source: str, panel_source: str):
    """The samples to model: one row per sample with its ``inputs`` and mean ``score``.

    Panel ids missing from the table are an error. Table rows without scores, failed fits
    (``success`` false) and rows with missing inputs are left out and listed in ``notes``;
    replicate rows of one sample (replicates fitted one by one) are averaged.
    Returns (frame indexed by sample_id with inputs + score columns, notes).
    """
    require_columns(table, ["sample_id", *inputs], table_source)
    table = table.copy()
    table["sample_id"] = table["sample_id"].astype(str).str.strip()
    notes: list[str] = []
    unknown = sorted(set(panel["sample_id"]) - set(table["sample_id"]))
    if unknown:
        more = f" (and {len(unknown) - 5} more)" if len(unknown) > 5 else ""
        raise DataError(
            f"{panel_source}: sample_id {', '.join(map(repr, unknown[:5]))}{more} not in the table {table_source}"
        )
    if "success" in table.columns:
        failed = ~table["success"].map(_truthy)
        if failed.any():
            notes.append(f"left out {int(failed.sum())} failed fit(s): {', '.join(table.loc[failed, 'sample_id'][:5])}")
            table = table[~failed]
    values = table[["sample_id", *inputs]].copy()
    text = []
    for col in inputs:
        numbers = pd.to_numeric(values[col], errors="coerce")
        bad = numbers.isna() & values[col].notna()
        text += [f"{col} of {sid}: {str(v)[:20]!r}" for sid, v in zip(values.loc[bad, "sample_id"], values.loc[bad, col])]
        values[col] = numbers
    missing = values[list(inputs)].isna().any(axis=1)
    if missing.any():
        named = f" (text in {', '.join(text[:3])}{' ...' if len(text) > 3 else ''})" if text else ""
        notes.append(f"left out {int(missing.sum())} row(s) with missing or non-numeric inputs: "
                     f"{', '.join(values.loc[missing, 'sample_id'][:5])}{named}")
        values = values[~missing]
    if values["sample_id"].duplicated().any():
        notes.append("averaged the replicate rows of each sample")
        values = values.groupby("sample_id", sort=False).mean()
    else:
        values = values.set_index("sample_id")
    scores = sample_means(panel)
    unscored = values.index.difference(scores.index)
    if len(unscored):
        notes.append(f"{len(unscored)} table sample(s) have no scores and are not used: {', '.join(unscored[:5])}")
    joined = values.join(scores, how="inner")
    if len(joined) < 5:
        raise DataError(f"{panel_source}: only {len(joined)} sample(s) have both scores and inputs; at least 5 are needed")
    return joined, notes


def describe_by(panel: pd.DataFrame, column: str, total: str | None = None) -> pd.DataFrame:
    """Tables 7.1/7.2: n, min, max, mean and std of the scores by ``column`` (+ a total row)."""
    g = panel.groupby(column, sort=True)["score"]
    out = pd.DataFrame({"n": g.size(), "min": g.min(), "max": g.max(), "mean": g.mean(), "std": g.std(ddof=1)})
    out.index.name = column
    if total:
        s = panel["score"]
        out.loc[total] = [s.size, s.min(), s.max(), s.mean(), s.std(ddof=1)]
    out["n"] = out["n"].astype(int)
    return out


def one_way_anova(panel: pd.DataFrame, by: str, alpha: float = 0.05, label: str | None = None) -> pd.DataFrame:
    """Table 7.3: one-way ANOVA of the scores by ``by`` (statsmodels OLS, type-I sums of squares).

    Rows: the factor (``label``), 'Within groups', 'Total'; columns SS, df, MS, F, p, F crit
    (the 1 - alpha quantile of F(df_between, df_within)).
    """
    from scipy import stats
    from statsmodels.formula.api import ols
    from statsmodels.stats.anova import anova_lm

    data = pd.DataFrame({"score": panel["score"].astype(float), "level": panel[by].astype(str)})
    if data["level"].nunique() < 2:
        raise DataError(f"ANOVA by {by!r} needs at least two levels, got {data['level'].nunique()}")
    if len(data) <= data["level"].nunique():
        raise DataError(f"ANOVA by {by!r} needs more scores than levels")
    aov = anova_lm(ols("score ~ C(level)", data=data).fit(), typ=1)
    ss_b, ss_w = float(aov.loc["C(level)", "sum_sq"]), float(aov.loc["Residual", "sum_sq"])
    df_b, df_w = int(aov.loc["C(level)", "df"]), int(aov.loc["Residual", "df"])
    f_value = float(aov.loc["C(level)", "F"])
    rows = {
        label or by: [ss_b, df_b, ss_b / df_b, f_value, float(aov.loc["C(level)", "PR(>F)"]), float(stats.f.ppf(1 - alpha, df_b, df_w))],
        "Within groups": [ss_w, df_w, ss_w / df_w, np.nan, np.nan, np.nan],
        "Total": [ss_b + ss_w, df_b + df_w, np.nan, np.nan, np.nan, np.nan],
    }
    out = pd.DataFrame.from_dict(rows, orient="index", columns=["SS", "df", "MS", "F", "p", "F crit"])
    out.index.name = "source of variation"
    out["df"] = out["df"].astype(int)
    return out


def lsd_comparisons(panel: pd.DataFrame, by: str, alpha: float = 0.05) -> pd.DataFrame:
    """Fisher's least significant difference between all pairs of levels of ``by``.

    t = (mean_a - mean_b) / sqrt(MSE (1/n_a + 1/n_b)) on the ANOVA's within-groups MSE and df.
    """
    from scipy import stats

    g = panel.groupby(by, sort=True)["score"]
    means, counts = g.mean(), g.size()
    df_w = int(len(panel) - len(means))
    mse = float(((panel["score"] - g.transform("mean")) ** 2).sum() / df_w)
    t_crit = float(stats.t.ppf(1 - alpha / 2, df_w))
    rows = []
    levels = list(means.index)
    for i, a in enumerate(levels):
        for b in levels[i + 1 :]:
            se = float(np.sqrt(mse * (1 / counts[a] + 1 / counts[b])))
            diff = float(means[a] - means[b])
            t = diff / se
            rows.append({"a": a, "b": b, "difference": diff, "se": se, "t": t,
                         "p": float(2 * stats.t.sf(abs(t), df_w)), "lsd": t_crit * se, "significant": abs(diff) > t_crit * se})
    return pd.DataFrame(rows)


def _truthy(value) -> bool:
    if isinstance(value, str):
        return value.strip().lower() in ("true", "1", "yes")
    try:
        return bool(value) and not (isinstance(value, float) and np.isnan(value))
    except (TypeError, ValueError):
        return False
