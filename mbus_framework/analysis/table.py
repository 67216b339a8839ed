"""Reading the campaign table that every analysis starts from (schema: docs/campaign-table.md)."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

from mbus_framework.errors import DataError

#: The four Kelvin-Voigt material properties, in the dissertation's order.
PROPERTIES = ("E_sigma", "eta_sigma", "E_tau", "eta_tau")
#: The four Kelvin-Voigt model parameters, in the dissertation's order.
PARAMETERS = ("k_sigma", "b_sigma", "k_tau", "b_tau")


def read_table(path: str | Path):
    """Read a campaign table (.csv or .parquet) as a pandas DataFrame; one-line errors."""
    import pandas as pd

    p = Path(path)
    if not p.is_file():
        raise DataError(f"{p}: table not found (expected a campaign properties.csv or .parquet)")
    try:
        if p.suffix.lower() == ".parquet":
            df = pd.read_parquet(p)
        else:
            df = pd.read_csv(p)
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DataError(f"{p}: cannot read table ({first[:200]})") from None
    if "sample_id" not in df.columns:
        raise DataError(f"{p}: column 'sample_id' is missing")
    return df


def require_columns(df, columns: Sequence[str], source: str) -> None:
    """Raise a one-line DataError naming every column of ``columns`` that ``df`` lacks."""
    missing = [c for c in columns if c not in df.columns]
    if missing:
        have = ", ".join(map(str, df.columns[:20]))
        raise DataError(f"{source}: missing column(s) {', '.join(missing)} (table has: {have})")
