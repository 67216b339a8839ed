"""Delimited text records (``.csv``, ``.tsv``, ``.txt``) -> columns t, u, y, with reader options.

:class:`TableOptions` (flat keys of ``backend.options``) describes files that are not plain
``t,u,y`` CSV: which column is which (``columns``, names or 0-based indices), the ``delimiter``
(default by suffix: ``,`` for .csv, tab for .tsv, runs of blanks for .txt; ``;`` when
``decimal: ','``), lines to skip before the header (``skip_rows``), a ``units_row`` under the
header, comment lines (``comment``, default ``#``) and a decimal comma (``decimal``).

Without options a header ``t,u,y`` (any order, extra columns, case, units such as ``t [s]`` or
``u (N)``) is read. When a file does not load, the one-line error names the option (and the
value) that would load it, found by looking at the file: a preamble before the header row
(``skip_rows``), another delimiter, a decimal comma, a units row, another comment character,
renamed columns or a headerless file (``columns``).
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from mbus_framework.errors import DataError

REQUIRED = ("t", "u", "y")
TEXT_SUFFIXES = (".csv", ".tsv", ".txt")
OPT = "backend.options"
UNIT = re.compile(r"^(.*?)\s*(?:\[([^\]]*)\]|\(([^)]*)\))\s*$")
NUMBER = re.compile(r"^[+-]?(\d+([.,]\d*)?|[.,]\d+)([eE][+-]?\d+)?$")
SCAN_LINES = 60


class TableOptions(BaseModel):
    """Reader options for delimited text records (flat keys of ``backend.options``)."""

    model_config = ConfigDict(extra="forbid")
    columns: dict[Literal["t", "u", "y"], str | int] | None = Field(
        None, description="which column is t, u, y: header names or 0-based indices, e.g. {t: time, u: 1, y: 2}")
    delimiter: str | None = Field(
        None, description="column separator (',', ';', 'tab', 'space'); default by suffix: .csv ',', .tsv tab, .txt blanks")
    skip_rows: int = Field(0, ge=0, description="lines to skip before the header row (a preamble)")
    units_row: bool = Field(False, description="the row under the header holds units (e.g. s,N,N)")
    comment: str = Field("#", min_length=1, max_length=3, description="lines starting with this are skipped")
    decimal: Literal[".", ","] = Field(".", description="decimal mark; ',' makes ';' the default delimiter")

    @field_validator("delimiter")
    @classmethod
    def _named(cls, v: str | None) -> str | None:
        if v is None:
            return v
        named = {"tab": "\t", "\\t": "\t", "space": " ", "whitespace": " ", "blank": " "}
        v = named.get(v.strip().lower(), v)
        if not v or len(v) > 3:
            raise ValueError("use one character (',', ';', '|'), 'tab' or 'space'")
        return v


TABLE_KEYS = tuple(TableOptions.model_fields)


def _delimiter(path: Path, o: TableOptions) -> str | None:
    """The separator to split by; None means runs of blanks."""
    if o.delimiter is not None:
        return None if o.delimiter == " " else o.delimiter
    suffix = path.suffix.lower()
    if suffix == ".tsv":
        return "\t"
    if o.decimal == ",":
        return ";"
    return None if suffix == ".txt" else ","


def _split(line: str, sep: str | None) -> list[str]:
    return [f.strip().strip('"').strip() for f in (line.split() if sep is None else line.split(sep))]


def _is_number(field: str, decimal: str) -> bool:
    if decimal == "." and "," in field:
        return False
    try:
        float(field.replace(",", ".") if decimal == "," else field)
        return True
    except ValueError:
        return False


def _numeric_row(fields: list[str], decimal: str) -> bool:
    return bool(fields) and all(_is_number(f, decimal) for f in fields)


def _name_and_unit(raw: str) -> tuple[str, str | None]:
    m = UNIT.match(raw)
    if m and m.group(1):
        return m.group(1).strip().lower(), (m.group(2) or m.group(3) or "").strip() or None
    return raw.strip().lower(), None


def read_table(path: Path, text: str, o: TableOptions | None = None,
               defaults: dict[str, str | int] | None = None) -> tuple[dict[str, np.ndarray], dict]:
    """Columns of a delimited text record and what was learnt (``units``, ``columns``).

    ``defaults`` maps each wanted role to the column taken when ``o.columns`` does not name it
    (default: t, u, y by name)."""
    o = o or TableOptions()
    defaults = defaults or {c: c for c in REQUIRED}
    sep = _delimiter(path, o)
    lines = [(k + 1, line) for k, line in enumerate(text.splitlines())][o.skip_rows:]
    comments = [(k, line) for k, line in lines if line.strip().startswith(o.comment)]
    rows = [(k, line) for k, line in lines if line.strip() and not line.strip().startswith(o.comment)]
    if not rows:
        raise DataError(f"{path}: empty: no header and no rows (missing columns t, u, y)")
    first_no, first = rows[0]
    head = _split(first, sep)
    header: list[str] | None
    if _numeric_row(head, o.decimal):
        header = None
        if comments and comments[-1][0] == first_no - 1:  # numpy.savetxt: '# t,u,y' above the numbers
            candidate = _split(comments[-1][1].strip()[len(o.comment):], sep)
            if all(c in [_name_and_unit(h)[0] for h in candidate] for c in REQUIRED) and len(candidate) == len(head):
                header = candidate
        body = rows
    else:
        header, body = head, rows[1:]
    units: list[str | None] = [None] * len(header or head)
    if header is not None:
        units = [_name_and_unit(h)[1] for h in header]
        if o.units_row:
            if not body:
                raise DataError(f"{path}: {OPT}.units_row is set but no row follows the header")
            units = _split(body[0][1], sep)
            body = body[1:]
    index = _resolve_columns(path, o, header, head, rows, sep, defaults)
    width = len(header) if header is not None else len(head)
    data = _parse(path, o, body, sep, width, header)
    meta: dict = {"columns": {c: (header[i] if header else i) for c, i in index.items()}}
    found = {c: units[i] for c, i in index.items() if i < len(units) and units[i]}
    if found:
        meta["units"] = found
    return {c: data[:, i] for c, i in index.items()}, meta


def read_pair(u_path: Path, u_text: str, y_path: Path, y_text: str,
              o: TableOptions | None = None) -> tuple[dict[str, np.ndarray], dict]:
    """Two single-channel files (e.g. generic scope exports ``time,value``): t and u from the
    first, y from the second; column 0 is the time and column 1 the value unless ``o.columns``
    names them (t and u in the first file, t and y in the second). Both must share the time base."""
    o = o or TableOptions()
    a, meta_u = read_table(u_path, u_text, o, {"t": 0, "u": 1})
    b, meta_y = read_table(y_path, y_text, o, {"t": 0, "y": 1})
    if a["t"].size != b["t"].size:
        raise DataError(f"{y_path}: {b['t'].size} samples but {u_path.name} has {a['t'].size} (not the same acquisition?)")
    step = abs(float(a["t"][1] - a["t"][0])) if a["t"].size > 1 else 0.0
    worst = float(np.max(np.abs(a["t"] - b["t"])))
    if worst > 0.5 * step:  # NaN (a bad value) is reported by the record check
        raise DataError(f"{y_path}: its time column differs from {u_path.name}'s by up to {worst:.3g} s "
                        f"(not the same acquisition?)")
    meta = {"columns": {**meta_u["columns"], "y": meta_y["columns"]["y"]}}
    units = {**meta_u.get("units", {}), **{k: v for k, v in meta_y.get("units", {}).items() if k == "y"}}
    if units:
        meta["units"] = units
    return {"t": a["t"], "u": a["u"], "y": b["y"]}, meta


def _resolve_columns(path: Path, o: TableOptions, header: list[str] | None, head: list[str],
                     rows: list[tuple[int, str]], sep: str | None, defaults: dict) -> dict[str, int]:
    names = [_name_and_unit(h)[0] for h in header] if header is not None else []
    raw = [h.strip().lower() for h in header] if header is not None else []
    wanted = {c: (o.columns or {}).get(c, d) for c, d in defaults.items()}
    index: dict[str, int] = {}
    missing = []
    for c, w in wanted.items():
        if isinstance(w, int):
            width = len(header) if header is not None else len(head)
            if not -width <= w < width:
                raise DataError(f"{path}: {OPT}.columns.{c} = {w} is out of range: the rows have {width} columns "
                                f"(0 ... {width - 1})")
            index[c] = w % width
        elif header is None:
            missing.append(c)
        elif w.strip().lower() in raw:
            index[c] = raw.index(w.strip().lower())
        elif _name_and_unit(w)[0] in names:
            index[c] = names.index(_name_and_unit(w)[0])
        else:
            missing.append(c)
    if missing:
        raise DataError(_diagnose(path, o, header, head, rows, sep, missing, wanted))
    return index


def _diagnose(path: Path, o: TableOptions, header, head, rows, sep, missing, wanted) -> str:
    """The one-line error for a header that does not give t, u, y: which option would load it."""
    first_no, first = rows[0]
    shown = first.strip()[:60]
    if header is None and o.columns is None:
        n = len(head)
        roles = list(wanted)
        hint = "{" + ", ".join(f"{c}: {k}" for k, c in enumerate(roles)) + "}" if n >= len(roles) else "(0-based indices)"
        return (f"{path}: no header row (line {first_no} is numbers, {n} columns); say which column is which "
                f"with {OPT}.columns: {hint}")
    # a comment character other than '#'
    mark = first.strip()[:1]
    if mark and not mark.isalnum() and mark not in "+-.\"'[(" and sum(
            line.strip().startswith(mark) for _, line in rows[:SCAN_LINES]) >= 1 and len(rows) > 1 \
            and _numeric_row(_split(rows[-1][1], sep), o.decimal):
        return f"{path}: line {first_no} {shown!r} looks like a comment; set {OPT}.comment: {mark!r}"
    # a header further down, after a preamble: skip_rows
    named = [w for w in wanted.values() if not isinstance(w, int)]
    for no, line in rows[1:SCAN_LINES] if named else []:
        for cand in (sep, ",", ";", "\t", None):
            fields = [_name_and_unit(f)[0] for f in _split(line, cand)]
            if all(w.strip().lower() in fields or _name_and_unit(w)[0] in fields for w in named):
                extra = "" if cand == sep else f" and {OPT}.delimiter: {_show(cand)}"
                return (f"{path}: the header row {line.strip()[:60]!r} is on line {no}; "
                        f"set {OPT}.skip_rows: {no - 1}{extra}")
    # a separator other than the one used
    if len(head) == 1 or (sep is None and len(head) < 3):
        for cand in (";", "\t", ",", "|", None):
            if cand == sep:
                continue
            fields = _split(first, cand)
            if len(fields) >= 2:
                body = [_split(line, cand) for _, line in rows[1:6]]
                if cand == ";" and any("," in f and _is_number(f, ",") for r in body for f in r):
                    return (f"{path}: header {shown!r} is separated by ';' and the numbers use a decimal comma; "
                            f"set {OPT}.decimal: ','")
                return f"{path}: header {shown!r} is not separated by {_show(sep)}; set {OPT}.delimiter: {_show(cand)}"
    names = ", ".join(f"{c} (looked for {wanted[c]!r})" if wanted[c] != c else c for c in missing)
    have = ",".join(header)[:80]
    suggestion = ", ".join(f"{c}: {header[k] if k < len(header) else '...'}" for k, c in enumerate(wanted))
    return (f"{path}: missing column(s) {names} in header {have!r}; say which column is which with "
            f"{OPT}.columns, e.g. {{{suggestion}}} (names or 0-based indices)")


def _show(sep: str | None) -> str:
    return {None: "'space'", "\t": "'tab'"}.get(sep, repr(sep))


def _parse(path: Path, o: TableOptions, body, sep, width: int, header) -> np.ndarray:
    if not body:
        raise DataError(f"{path}: no data rows")
    out = np.empty((len(body), width))
    for r, (no, line) in enumerate(body):
        fields = _split(line, sep)
        if sep is not None and len(fields) == width + 1 and fields[-1] == "":
            fields = fields[:-1]  # a trailing separator
        if len(fields) != width:
            hint = ""
            if o.decimal == "." and sep == "," and len(fields) > width:
                hint = f"; a decimal comma? set {OPT}.decimal: ','"
            raise DataError(f"{path}: line {no} has {len(fields)} values but the "
                            f"{'header' if header is not None else 'first row'} has {width}{hint}")
        for k, f in enumerate(fields):
            try:
                out[r, k] = float(f.replace(",", ".") if o.decimal == "," else f)
            except ValueError:
                hint = _bad_value(path, o, no, line, f, r, body, sep, header)
                if hint:
                    raise DataError(hint) from None
                out[r, k] = np.nan  # reported by the record check with its column and row
    return out


def _bad_value(path: Path, o: TableOptions, no: int, line: str, field: str, r: int, body, sep, header) -> str | None:
    """The error for a value that is not a number when an option explains it, else None."""
    msg = f"{path}: line {no}: {field[:30]!r} is not a number"
    if o.decimal == "." and NUMBER.match(field) and "," in field:
        return f"{msg}; a decimal comma? set {OPT}.decimal: ','"
    if r == 0 and header is not None and not o.units_row and len(body) > 1 and \
            _numeric_row(_split(body[1][1], sep), o.decimal):
        return f"{msg} (line {line.strip()[:40]!r} under the header); if it holds units set {OPT}.units_row: true"
    return None
