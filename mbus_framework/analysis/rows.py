"""Which rows of a campaign table an analysis may use."""
from __future__ import annotations

from typing import Sequence

import numpy as np


def failed_mask(df) -> np.ndarray:
    """True for rows whose ``error`` column holds text (failed fits); all False without one."""
    if "error" not in df.columns:
        return np.zeros(len(df), dtype=bool)
    err = df["error"]
    return (err.notna() & (err.astype(str).str.strip() != "")).to_numpy()


def usable_rows(df, columns: Sequence[str]):
    """(rows without an error and with finite values in ``columns``, counts).

    ``counts`` = {"rows": all rows, "failed": rows with an error, "missing": other rows
    lacking a finite value in one of ``columns``, "used": rows kept, and "non_numeric": the
    first few cells that hold text instead of a number, as "column of sample: 'text'"}.
    """
    import pandas as pd

    failed = failed_mask(df)
    raw = df[list(columns)]
    values = raw.apply(pd.to_numeric, errors="coerce")
    finite = np.isfinite(values.to_numpy(dtype=float)).all(axis=1) if len(columns) else np.ones(len(df), bool)
    keep = ~failed & finite
    counts = {"rows": int(len(df)), "failed": int(failed.sum()), "missing": int((~failed & ~finite).sum()),
              "used": int(keep.sum())}
    text = values.isna() & raw.notna() & ~failed[:, None] if len(columns) else None
    if text is not None and text.to_numpy().any():
        ids = df["sample_id"].astype(str) if "sample_id" in df.columns else pd.Series(
            [f"row {i + 1}" for i in range(len(df))], index=df.index)
        cells = [(col, ids.iloc[i], raw[col].iloc[i]) for i, col in zip(*np.nonzero(text.to_numpy()))
                 for col in [raw.columns[col]]]
        counts["non_numeric"] = [f"{c} of {sid}: {str(v)[:20]!r}" for c, sid, v in cells[:3]] + (
            [f"{len(cells) - 3} more"] if len(cells) > 3 else [])
    out = df.loc[keep].copy()
    out[list(columns)] = values.loc[keep]
    return out, counts


def describe_exclusions(counts: dict, what: str = "rows") -> str:
    """'used 28 of 30 rows (excluded: 1 failed fit, 1 with missing values)'."""
    parts = []
    if counts.get("failed"):
        parts.append(f"{counts['failed']} failed (error)")
    if counts.get("missing"):
        text = counts.get("non_numeric")
        parts.append(f"{counts['missing']} with missing or non-numeric values"
                     + (f" (text in {', '.join(text)})" if text else ""))
    tail = f" (excluded: {', '.join(parts)})" if parts else ""
    return f"used {counts['used']} of {counts['rows']} {what}{tail}"
