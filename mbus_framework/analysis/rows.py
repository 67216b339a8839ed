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
    lacking a finite value in one of ``columns``, "used": rows kept}.
    """
    import pandas as pd

    failed = failed_mask(df)
    values = df[list(columns)].apply(pd.to_numeric, errors="coerce")
    finite = np.isfinite(values.to_numpy(dtype=float)).all(axis=1) if len(columns) else np.ones(len(df), bool)
    keep = ~failed & finite
    counts = {"rows": int(len(df)), "failed": int(failed.sum()), "missing": int((~failed & ~finite).sum()),
              "used": int(keep.sum())}
    out = df.loc[keep].copy()
    out[list(columns)] = values.loc[keep]
    return out, counts


def describe_exclusions(counts: dict, what: str = "rows") -> str:
    """'used 28 of 30 rows (excluded: 1 failed fit, 1 with missing values)'."""
    parts = []
    if counts.get("failed"):
        parts.append(f"{counts['failed']} failed (error)")
    if counts.get("missing"):
        parts.append(f"{counts['missing']} with missing values")
    tail = f" (excluded: {', '.join(parts)})" if parts else ""
    return f"used {counts['used']} of {counts['rows']} {what}{tail}"
