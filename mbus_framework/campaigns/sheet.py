"""The sample sheet: one row per record (a CSV file or an inline list of mappings).

Columns (docs/campaign-format.md): ``sample_id`` (required), ``replicate`` (positive integer,
default 1), ``data`` (a recording for the file backend, relative to the sheet), the group-label
and covariate columns the campaign names, and dotted run-config keys (per-sample overrides,
read as YAML like ``--set``). Rows are numbered as a spreadsheet shows them (the header is
row 1). Every problem is collected as one line naming the sheet, row and column.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import yaml

from mbus_framework.campaigns.problems import Problems
from mbus_framework.pipeline.config import RunConfig
from mbus_framework.suggest import did_you_mean

SAMPLE_ID, REPLICATE, DATA = "sample_id", "replicate", "data"
RESERVED = (SAMPLE_ID, REPLICATE, DATA)
#: Top-level run-config sections a dotted override column may start with.
CONFIG_SECTIONS = tuple(name for name in RunConfig.model_fields if name != "title")


@dataclass(frozen=True)
class SheetRow:
    """One record of the sheet. ``overrides`` maps dotted config keys to YAML text (``--set``)."""

    where: str
    sample_id: str
    replicate: int
    data: Path | None = None
    overrides: dict[str, str] = field(default_factory=dict)
    groups: dict[str, Any] = field(default_factory=dict)
    covariates: dict[str, Any] = field(default_factory=dict)
    folder: Path = Path(".")
    """The sheet's folder: relative paths in its cells are relative to it."""

    def at(self, column: str) -> str:
        """``'<sheet>: row N, column <column>'`` for error messages."""
        return f"{self.where}, column {column}"


def read_sheet(
    samples: str | list,
    campaign_file: Path,
    groups: Sequence[str],
    covariates: Sequence[str],
    problems: Problems,
) -> list[SheetRow]:
    """Rows of the sheet ``samples`` (a CSV path relative to the campaign file, or a list of
    mappings); problems are added to ``problems``, never raised."""
    _check_names(groups, covariates, problems)
    if isinstance(samples, str):
        path = campaign_file.parent / samples
        cells = _read_csv(path, problems)
        base = path.parent
    else:
        cells = _inline(samples, campaign_file, problems)
        base = campaign_file.parent
    if cells is None:
        return []
    header, records = cells
    known = _check_header(header, groups, covariates, records, problems)
    rows: list[SheetRow] = []
    seen: dict[tuple[str, int], str] = {}
    for where, record in records:
        row = _row(where, record, known, base, groups, covariates, problems)
        if row is None:
            continue
        first = seen.get((row.sample_id, row.replicate))
        if first is not None:
            problems.add(f"{row.at(REPLICATE)}: sample '{row.sample_id}' replicate {row.replicate} is already "
                         f"on {first.rpartition(': ')[2]}; (sample_id, replicate) must be unique")
            continue
        seen[row.sample_id, row.replicate] = where
        rows.append(row)
    if not rows and not problems:
        problems.add(f"{_sheet_name(samples, campaign_file)}: the sample sheet has no rows")
    return rows


def _sheet_name(samples, campaign_file: Path) -> str:
    return str(campaign_file.parent / samples) if isinstance(samples, str) else f"{campaign_file}: campaign.samples"


def _check_names(groups: Sequence[str], covariates: Sequence[str], problems: Problems) -> None:
    for kind, names in (("groups", groups), ("covariates", covariates)):
        for name in names:
            if name in RESERVED or "." in name:
                problems.add(f"campaign.{kind}: '{name}' cannot be a {kind[:-1]} column (reserved or a config key)")
    for name in set(groups) & set(covariates):
        problems.add(f"campaign.covariates: '{name}' is also in campaign.groups")


def _read_csv(path: Path, problems: Problems):
    try:
        with open(path, encoding="utf-8-sig", newline="") as fh:
            reader = csv.reader(fh)
            header: list[str] | None = None
            records = []
            for cells in reader:
                if not any(c.strip() for c in cells):
                    continue
                if header is None:
                    header = [c.strip() for c in cells]
                    continue
                where = f"{path}: row {reader.line_num}"
                if len(cells) != len(header):
                    problems.add(f"{where}: {len(cells)} values but the header has {len(header)} columns")
                    continue
                records.append((where, {h: c.strip() for h, c in zip(header, cells)}))
    except FileNotFoundError:
        problems.add(f"{path}: sample sheet not found")
        return None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        problems.add(f"{path}: cannot read the sample sheet ({type(exc).__name__}: {str(exc)[:120]})")
        return None
    if header is None:
        problems.add(f"{path}: the sample sheet is empty")
        return None
    for i, name in enumerate(header):
        if not name:
            problems.add(f"{path}: row 1, column {i + 1}: a column has no name")
        elif header.index(name) != i:
            problems.add(f"{path}: row 1: column '{name}' appears twice")
    return [h for h in header if h], records


def _inline(samples: list, campaign_file: Path, problems: Problems):
    header: list[str] = []
    records = []
    for i, item in enumerate(samples):
        where = f"{campaign_file}: campaign.samples[{i}]"
        if not isinstance(item, dict):
            problems.add(f"{where}: a sample must be a mapping of column: value, not {type(item).__name__}")
            continue
        cells = {str(k): _cell(v) for k, v in item.items()}
        header += [k for k in cells if k not in header]
        records.append((where, cells))
    return header, records


def _cell(value: Any) -> str:
    """An inline value as the text a CSV cell would hold (YAML flow style for non-strings)."""
    if value is None:
        return ""
    if isinstance(value, str):
        return value
    return yaml.safe_dump(value, default_flow_style=True, width=10**6).strip().removesuffix("\n...").strip()


def _check_header(header, groups, covariates, records, problems: Problems) -> set[str]:
    """Columns that are known; adds a problem for every unknown or missing column."""
    sheet = records[0][0].rpartition(": ")[0] if records else "sample sheet"
    inline = "campaign.samples[" in (records[0][0] if records else "")
    if SAMPLE_ID not in header:
        problems.add(f"{sheet}: column '{SAMPLE_ID}' is missing (every row needs a sample id)")
    for kind, names in (("groups", groups), ("covariates", covariates)):
        for name in names:
            if name not in header:
                problems.add(f"campaign.{kind}: '{name}' is not a column of {sheet}")
    allowed = [*RESERVED, *groups, *covariates]
    known = set()
    for name in header:
        if name in allowed or name.split(".")[0] in CONFIG_SECTIONS and "." in name:
            known.add(name)
            continue
        hint = did_you_mean(name, allowed + [f"{s}." for s in CONFIG_SECTIONS])
        where = f"{sheet}: column '{name}'" if not inline else f"{sheet}: key '{name}'"
        problems.add(
            f"{where}: unknown column{hint}; a column is {', '.join(RESERVED)}, a name in campaign.groups or "
            f"campaign.covariates, or a dotted run-config key such as sample.density or backend.options.seed"
        )
    return known


def _row(where, record, known, base: Path, groups, covariates, problems: Problems) -> SheetRow | None:
    row = SheetRow(where, "", 1)
    ok = True
    sample_id = record.get(SAMPLE_ID, "")
    if not sample_id:
        problems.add(f"{row.at(SAMPLE_ID)}: the sample id is empty")
        ok = False
    replicate = 1
    text = record.get(REPLICATE, "")
    if text:
        try:
            replicate = int(text)
            if replicate < 1:
                raise ValueError
        except ValueError:
            problems.add(f"{row.at(REPLICATE)}: must be a positive integer (got {text!r})")
            ok = False
    data = None
    if record.get(DATA):
        data = base / record[DATA]
        if not data.exists():
            problems.add(f"{row.at(DATA)}: file not found: {data}")
            ok = False
    labels = {}
    for name in groups:
        labels[name] = record.get(name, "")
        if name in record and not labels[name]:
            problems.add(f"{row.at(name)}: the group label is empty")
            ok = False
    overrides = {k: v for k, v in record.items() if k in known and "." in k and k not in RESERVED and v != ""}
    if not ok:
        return None
    return SheetRow(
        where,
        sample_id,
        replicate,
        data.resolve() if data is not None else None,
        overrides,
        labels,
        {name: record.get(name, "") for name in covariates},
        base.resolve(),
    )
