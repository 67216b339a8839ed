"""The group summary of a campaign (Tables 4.2/4.3) as data, text, CSV and plots: what a
campaign prints and what a campaign report page is built on."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from mbus_framework.campaigns.plots import property_plots
from mbus_framework.campaigns.summary import group_summary, summary_text
from mbus_framework.campaigns.table import property_names
from mbus_framework.errors import DataError
from mbus_framework.pipeline.storage import atomic_write_bytes, atomic_write_text

CAMPAIGN_JSON = "campaign.json"


@dataclass
class GroupReport:
    """summary: one row per group (pandas DataFrame, also ``group_summary.csv``);
    text: the summary as printed; files: name -> path; plots: property -> PNG path."""

    summary: Any
    text: str
    files: dict[str, Path] = field(default_factory=dict)
    plots: dict[str, Path] = field(default_factory=dict)


def group_report(
    table: Any,
    groups: Sequence[str] | None = None,
    out_dir: str | Path | None = None,
    title: str = "",
    quantities: Sequence[str] | None = None,
    plots: bool = True,
    units: dict[str, str] | None = None,
) -> GroupReport:
    """Summarise ``table`` by ``groups`` and write ``group_summary.csv``, ``group_summary.txt``
    and ``plots/<property>_by_group.png`` into ``out_dir``.

    ``table`` is a DataFrame, a properties .csv/.parquet file, or a campaign folder (its
    ``properties.parquet``; ``groups``, ``title`` and ``out_dir`` then default to the campaign's).
    ``quantities`` defaults to the table's material properties; ``units`` (name -> unit, e.g.
    ``{"E_sigma": "Pa"}``) labels the plots' axes (a campaign folder's come from campaign.json).
    """
    df, groups, out_dir, title = _inputs(table, groups, out_dir, title)
    if units is None and isinstance(table, (str, Path)) and Path(table).is_dir():
        meta_file = Path(table) / CAMPAIGN_JSON
        units = json.loads(meta_file.read_text(encoding="utf-8")).get("units") if meta_file.is_file() else None
    quantities = list(quantities or property_names(df))
    summary = group_summary(df, groups, quantities)
    text = summary_text(summary, groups, quantities, title or "campaign")
    report = GroupReport(summary, text)
    if out_dir is not None:
        out = Path(out_dir)
        report.files["group_summary_csv"] = atomic_write_bytes(out / "group_summary.csv",
                                                               summary.to_csv(index=False).encode("utf-8"))
        report.files["group_summary_text"] = atomic_write_text(out / "group_summary.txt", text + "\n")
        if plots and len(df):
            report.plots = property_plots(df, summary, groups, quantities, out / "plots", title, units or {})
    return report


def _inputs(table, groups, out_dir, title):
    import pandas as pd

    if isinstance(table, pd.DataFrame):
        return table, list(groups or []), out_dir, title
    path = Path(table)
    if path.is_dir():
        meta_file = path / CAMPAIGN_JSON
        meta = json.loads(meta_file.read_text(encoding="utf-8")) if meta_file.is_file() else {}
        groups = list(groups if groups is not None else meta.get("groups", []))
        return _read(path / "properties.parquet"), groups, out_dir or path, title or meta.get("title", "")
    return _read(path), list(groups or []), out_dir, title


def _read(path: Path):
    import pandas as pd

    if not path.is_file():
        raise DataError(f"{path}: table not found (expected a campaign properties.csv or .parquet)")
    try:
        return pd.read_parquet(path) if path.suffix.lower() == ".parquet" else pd.read_csv(path)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot read table ({str(exc).splitlines()[0][:200]})") from None
