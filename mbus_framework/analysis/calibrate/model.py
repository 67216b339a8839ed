"""Calibration of MBUS properties against conventional tests (Chapter 6, Tables 6.1 and 6.2).

Per property p and MBUS variant (e.g. before and after transducer compensation), the MBUS
value is regressed on the conventional one, ``p = intercept + slope * conv_p`` (Table 6.1:
slope, intercept, r; here also their standard errors, t-tests and confidence intervals, see
:mod:`mbus_framework.analysis.calibrate.regression`). The conventional values are the ``conv_<p>``
columns (:mod:`mbus_framework.analysis.conventional.sheet`): compression E and eta for the
normal properties, rheometer E' and eta' for the shear ones, joined by ``sample_id``.

Variants: a table with a ``compensation`` column (or another ``--variant-column``) is split by
its values; several tables (``NAME=PATH``) are one variant each. A sample with several rows
(replicates fitted one by one) is averaged to one row per sample first, so each sample counts
once in the regression.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from mbus_framework.errors import DataError
from mbus_framework.analysis.conventional.sheet import PREFIX
from mbus_framework.analysis.calibrate.regression import LineFit, fit_line
from mbus_framework.analysis.rows import failed_mask, usable_rows
from mbus_framework.analysis.table import PROPERTIES, read_table

#: Chapter 6 figure of each property (Figs 6.4-6.7).
FIGURES = {"E_sigma": "6.4", "eta_sigma": "6.5", "E_tau": "6.6", "eta_tau": "6.7"}
CONVENTIONAL_LABEL = {"E_sigma": "compression E", "eta_sigma": "compression eta",
                      "E_tau": "rheometer E'", "eta_tau": "rheometer eta'"}


def parse_table_spec(spec: str) -> tuple[str | None, Path]:
    """``"NAME=PATH"`` -> (NAME, PATH); ``"PATH"`` -> (None, PATH)."""
    name, sep, rest = spec.partition("=")
    if sep and name and "/" not in name and not Path(spec).exists():
        return name.strip(), Path(rest)
    return None, Path(spec)


def load_variants(specs: Sequence[str], variant_column: str = "compensation") -> dict[str, "object"]:
    """{variant name: rows} from table specs (see module docstring); failed rows are kept here."""
    variants: dict[str, object] = {}
    parsed = [parse_table_spec(s) for s in specs]
    for name, path in parsed:
        df = read_table(path)
        if variant_column in df.columns:
            parts = {(f"{name} {v}" if name else v): df[df[variant_column].astype(str) == v].copy()
                     for v in dict.fromkeys(df[variant_column].astype(str))}
        else:
            parts = {name or (path.resolve().parent.name if len(parsed) > 1 else "MBUS"): df}
        for label, part in parts.items():
            part.attrs["source"] = str(path)
            variants[_unique(label, variants, path)] = part
    return variants


def _unique(label: str, taken, path: Path) -> str:
    if label in taken:
        raise DataError(f"{path}: variant '{label}' appears twice; name the tables (NAME=PATH)")
    return label


def one_row_per_sample(df):
    """Average the numeric columns of rows sharing a ``sample_id`` (failed rows dropped first)."""
    df = df.loc[~failed_mask(df)]
    if not df["sample_id"].duplicated().any():
        return df
    numeric = df.select_dtypes(include="number").columns
    grouped = df.groupby("sample_id", sort=False)
    out = grouped[list(numeric)].mean()
    rest = [c for c in df.columns if c not in numeric and c != "sample_id"]
    if rest:
        out = out.join(grouped[rest].first())
    return out.reset_index()


def attach_conventional(df, conventional, source: str = "<table>"):
    """Join the per-sample conventional table (``conv_*``) to ``df`` by ``sample_id``."""
    if conventional is None:
        if not any(c.startswith(PREFIX) for c in df.columns):
            raise DataError(f"{source}: no conventional values: give --conventional SHEET "
                            f"or columns {PREFIX}<property> in the table")
        return df
    overlap = [c for c in conventional.columns if c != "sample_id" and c in df.columns]
    left = df.drop(columns=overlap)
    left = left.assign(sample_id=left["sample_id"].astype(str))
    merged = left.merge(conventional, on="sample_id", how="left")
    conv_cols = [c for c in conventional.columns if c != "sample_id"]
    if conv_cols and not merged[conv_cols].notna().any(axis=1).any():
        raise DataError(f"{source}: no sample_id of the table is in the conventional sheet "
                        f"(table ids such as {', '.join(left['sample_id'].astype(str).head(3))})")
    return merged


@dataclass
class CalibrationAnalysis:
    """Regressions of every (variant, property) and the rows they used."""

    properties: list[str]
    variants: list[str]
    fits: dict[tuple[str, str], LineFit]
    rows: dict[str, object]
    counts: dict[tuple[str, str], dict]
    level: float
    notes: list[str] = field(default_factory=list)


def calibrate(variants: dict, conventional=None, properties: Sequence[str] | None = None,
              level: float = 0.95) -> CalibrationAnalysis:
    """Fit MBUS = intercept + slope * conventional for each variant and property."""
    requested = list(properties) if properties else list(PROPERTIES)
    fits, rows, counts, notes = {}, {}, {}, []
    found: list[str] = []
    for variant, df in variants.items():
        source = df.attrs.get("source", "<table>")
        n_rows = len(df)
        n_failed = int(failed_mask(df).sum())
        merged = attach_conventional(one_row_per_sample(df), conventional, source)
        if len(merged) < n_rows - n_failed:
            notes.append(f"{variant}: averaged {n_rows - n_failed} rows into {len(merged)} samples")
        rows[variant] = merged
        for prop in requested:
            if prop not in merged.columns or PREFIX + prop not in merged.columns:
                continue
            used, count = usable_rows(merged, [prop, PREFIX + prop])
            count["failed"] = n_failed
            count["rows"] = count["used"] + count["missing"] + n_failed
            fits[(variant, prop)] = fit_line(used[PREFIX + prop], used[prop], level,
                                             where=f"{source}: {variant} {prop}")
            counts[(variant, prop)] = count
            if prop not in found:
                found.append(prop)
    if not fits:
        raise DataError(f"no property has both an MBUS column and a {PREFIX}<property> column "
                        f"(looked for {', '.join(requested)})")
    return CalibrationAnalysis(properties=[p for p in requested if p in found], variants=list(variants),
                               fits=fits, rows=rows, counts=counts, level=level, notes=notes)


def _sci(value: float) -> str:
    """Table 6.1's number style: 7.387E+4, -9.824E+10; plain (43.945, 0.436) for 0.01 <= |v| < 1000."""
    if value == 0 or not np.isfinite(value):
        return str(value)
    if 0.01 <= abs(value) < 1000:
        return f"{value:.3f}"
    mantissa, exponent = f"{value:.3E}".split("E")
    return f"{mantissa}E{int(exponent):+d}"


def table_6_1(analysis: CalibrationAnalysis, star_level: float = 0.01):
    """Slope, intercept and r per property and variant; ``*``: r significant at ``star_level``."""
    import pandas as pd

    cols = pd.MultiIndex.from_product([analysis.variants, ["Slope", "Intercept", "r"]])
    data = []
    for prop in analysis.properties:
        row = []
        for variant in analysis.variants:
            fit = analysis.fits.get((variant, prop))
            if fit is None:
                row += ["", "", ""]
                continue
            row += [_sci(fit.slope), _sci(fit.intercept), f"{fit.r:.3f}" + ("*" if fit.r_p < star_level else "")]
        data.append(row)
    return pd.DataFrame(data, index=pd.Index(analysis.properties, name="Mechanical Property"), columns=cols)


def table_6_2(analysis: CalibrationAnalysis):
    """Minimum, maximum, mean and standard deviation: conventional, then each MBUS variant."""
    import pandas as pd

    stats = ("Minimum", "Maximum", "Mean", "Std. Deviation")

    def describe(values) -> list[float]:
        v = pd.to_numeric(pd.Series(values), errors="coerce").to_numpy(dtype=float)  # text cells: NaN
        v = v[np.isfinite(v)]
        if v.size == 0:
            return [np.nan] * 4
        return [v.min(), v.max(), v.mean(), v.std(ddof=1) if v.size > 1 else np.nan]

    conv = pd.concat([r[["sample_id"] + [PREFIX + p for p in analysis.properties if PREFIX + p in r.columns]]
                      for r in analysis.rows.values()]).drop_duplicates("sample_id")
    blocks = {"Conventionally measured": {p: describe(conv.get(PREFIX + p, [])) for p in analysis.properties}}
    for variant in analysis.variants:
        rows = analysis.rows[variant]
        blocks["MBUS" if variant == "MBUS" else f"MBUS {variant}"] = {p: describe(rows[p]) if p in rows.columns else [np.nan] * 4
                                     for p in analysis.properties}
    index = pd.MultiIndex.from_tuples([(b, s) for b in blocks for s in stats], names=["measurement", "statistic"])
    data = [[blocks[b][p][i] for p in analysis.properties] for b in blocks for i in range(4)]
    return pd.DataFrame(data, index=index, columns=analysis.properties)


def regression_frame(analysis: CalibrationAnalysis):
    """Every statistic of every regression, one row per (variant, property)."""
    import pandas as pd

    rows = []
    for (variant, prop), fit in analysis.fits.items():
        rows.append({"variant": variant, "property": prop, "conventional": CONVENTIONAL_LABEL.get(prop, ""),
                     **fit.as_dict(), "excluded_failed": analysis.counts[(variant, prop)]["failed"],
                     "excluded_missing": analysis.counts[(variant, prop)]["missing"]})
    return pd.DataFrame(rows)
