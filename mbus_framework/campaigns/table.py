"""The campaign table as a pandas DataFrame with fixed dtypes, written as CSV and Parquet
(schema: docs/campaign-table.md)."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from mbus_framework.pipeline.storage import atomic_write_bytes

#: Text columns (pandas "string" dtype, missing when empty); every other non-label column is float64.
TEXT = ("sample_id", "replicates", "replicates_reason", "warnings", "error", "run_dir")


def build_table(rows: Sequence[dict[str, Any]], groups: Sequence[str], covariates: Sequence[str]):
    """DataFrame of ``rows`` with the schema's dtypes: ids, labels and text as pandas "string"
    (missing = NA), ``replicate`` a nullable integer, ``n_replicates`` int64, ``success`` bool,
    covariates float64 when every value is a number (else text), everything else float64."""
    import pandas as pd

    columns: list[str] = []
    for row in rows:
        columns += [k for k in row if k not in columns]
    df = pd.DataFrame(list(rows), columns=columns)
    for col in df.columns:
        if col in covariates:
            df[col] = _covariate(df[col])
        elif col in TEXT or col in groups:
            df[col] = _text(df[col])
        elif col == "replicate":
            df[col] = pd.array([None if v is None or v != v else int(v) for v in df[col]], dtype="Int64")
        elif col == "n_replicates":
            df[col] = df[col].astype("int64")
        elif col == "success":
            df[col] = df[col].astype(bool)
        else:
            df[col] = pd.to_numeric(df[col], errors="coerce").astype("float64")
    return df


def _text(values):
    import pandas as pd

    return pd.array([None if _missing(v) else str(v) for v in values], dtype="string")


def _missing(v) -> bool:
    return v is None or (isinstance(v, float) and np.isnan(v)) or (isinstance(v, str) and not v.strip())


def _covariate(values):
    """Numbers when every non-empty value parses as one (empty -> NaN), else text."""
    import pandas as pd

    present = [v for v in values if not _missing(v)]
    numeric = pd.to_numeric(pd.Series(present, dtype=object), errors="coerce")
    if numeric.notna().all():
        return pd.to_numeric(pd.Series([None if _missing(v) else v for v in values], dtype=object)).astype("float64")
    return _text(values)


def write_table(df, out_dir: str | Path, stem: str = "properties") -> dict[str, Path]:
    """``<stem>.csv`` (full float precision, empty for missing) and ``<stem>.parquet``."""
    import io

    out = Path(out_dir)
    buf = io.StringIO()
    df.to_csv(buf, index=False)
    pq = io.BytesIO()
    df.to_parquet(pq, index=False)
    return {
        f"{stem}_csv": atomic_write_bytes(out / f"{stem}.csv", buf.getvalue().encode("utf-8")),
        f"{stem}_parquet": atomic_write_bytes(out / f"{stem}.parquet", pq.getvalue()),
    }


def property_names(df) -> list[str]:
    """Material properties of the table: the columns that have a 95 % interval."""
    return [c[: -len("_ci_low")] for c in df.columns if c.endswith("_ci_low") and c[: -len("_ci_low")] in df.columns]


def parameter_names(df) -> list[str]:
    """Model (and nuisance) parameters: columns with a standard error but no interval."""
    props = set(property_names(df))
    return [c[:-3] for c in df.columns if c.endswith("_se") and c[:-3] in df.columns and c[:-3] not in props]
