"""CSV files a GDS-2000 saves to its USB disk (one file per channel, e.g. ``A0001CH1.CSV``).

Layout: header rows ``key,value[,]`` (``Memory Length``, ``Source``, ``Vertical Units``,
``Vertical Scale``, ``Vertical Position``, ``Horizontal Scale``, ``Sampling Period``,
``Firmwave`` (sic), ...; the row set varies with the firmware) followed by the data rows, in
one of two forms:

* raw samples ("Fast"): one integer code per row; volts = code * ``Vertical Scale`` / 25,
  t_i = i * ``Sampling Period`` [s];
* ``time,value`` pairs ("Detail", header ``Mode,Detail``): seconds and volts as printed.

Numbers may carry SI prefixes and units (``500mV``, ``2.5uS``). Problems raise
:class:`~mbus_framework.errors.DataError` naming the file.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mbus_framework.errors import DataError
from mbus_framework.pipeline.storage import read_regular_file

COUNTS_PER_DIVISION = 25.0
PERIOD_RANGE = (1e-12, 100.0)
"""Plausible sampling period [s]."""
_NUMBER = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([pnuµmkMG]?)([A-Za-z/]*)\s*$")
_PREFIX = {"": 1.0, "p": 1e-12, "n": 1e-9, "u": 1e-6, "µ": 1e-6, "m": 1e-3, "k": 1e3, "M": 1e6, "G": 1e9}


@dataclass
class CsvTrace:
    """One channel from a GDS-2000 CSV: t [s] (uniform), volts [V], the header and the layout."""

    path: Path
    t: np.ndarray
    volts: np.ndarray
    header: dict[str, str]
    layout: str
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])


def parse_number(text: str) -> float:
    """``'5.000E-01'``, ``'500mV'``, ``'2.5uS'`` -> float (SI prefix applied; unit ignored)."""
    m = _NUMBER.match(text)
    if not m:
        raise ValueError(text)
    value, prefix, _unit = m.groups()
    number = float(value) * _PREFIX[prefix]
    if not np.isfinite(number):
        raise ValueError(text)
    return number


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_gds_csv(path: str | Path) -> CsvTrace:
    """Read one channel file; raises DataError naming the file for anything malformed."""
    path = Path(path)
    raw_text = read_regular_file(path, "GDS-2000 CSV file")
    if raw_text[:2] in (b"\xff\xfe", b"\xfe\xff"):
        try:
            raw_text = raw_text.decode("utf-16").encode("utf-8")
        except UnicodeDecodeError:
            raise DataError(f"{path}: starts with a UTF-16 byte-order mark but is not UTF-16 text") from None
    try:
        text = raw_text.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw_text.decode("latin-1")
    lines = text.splitlines()
    header: dict[str, str] = {}
    data_start = None
    for i, line in enumerate(lines):
        fields = [f.strip() for f in line.split(",")]
        while fields and fields[-1] == "":
            fields.pop()
        if not fields:
            continue
        if _is_number(fields[0]):
            data_start = i
            break
        header[fields[0]] = fields[1] if len(fields) > 1 else ""
    if data_start is None:
        raise DataError(f"{path}: no data rows after the header (not a GDS-2000 CSV export?)")
    if not header:
        raise DataError(f"{path}: no 'key,value' header rows (not a GDS-2000 CSV export; "
                        f"for a t,u,y record use the header t,u,y)")
    rows = []
    for i in range(data_start, len(lines)):
        fields = [f.strip() for f in lines[i].split(",")]
        while fields and fields[-1] == "":
            fields.pop()
        if not fields:
            continue
        try:
            row = [float(f) for f in fields]
        except ValueError:
            raise DataError(f"{path}: line {i + 1}: malformed data row {lines[i].strip()[:60]!r}") from None
        if not all(np.isfinite(row)):
            raise DataError(f"{path}: line {i + 1}: non-finite value in data row {lines[i].strip()[:60]!r}")
        rows.append(row)
    widths = {len(r) for r in rows}
    if len(widths) != 1:
        raise DataError(f"{path}: data rows have differing numbers of values ({sorted(widths)})")
    width = widths.pop()
    mode = header.get("Mode", "").strip().lower()
    if width == 1 and mode != "detail":
        trace = _raw_layout(path, header, np.array([r[0] for r in rows]))
    elif width == 2:
        trace = _time_value_layout(path, header, np.array(rows))
    else:
        raise DataError(f"{path}: data rows have {width} values (expected one raw code, or time,value)")
    length = header.get("Memory Length")
    if length is not None:
        try:
            expected = int(parse_number(length))
        except ValueError:
            raise DataError(f"{path}: header 'Memory Length' is not a number ({length[:40]!r})") from None
        if expected != trace.volts.size:
            raise DataError(f"{path}: header says Memory Length {expected} but the file has "
                            f"{trace.volts.size} samples (truncated file?)")
    if trace.volts.size < 16:
        raise DataError(f"{path}: only {trace.volts.size} samples")
    return trace


def _header_number(path: Path, header: dict[str, str], key: str) -> float:
    if key not in header:
        raise DataError(f"{path}: header row '{key}' missing (needed to scale the raw samples)")
    try:
        return parse_number(header[key])
    except ValueError:
        raise DataError(f"{path}: header '{key}' is not a number ({header[key][:40]!r})") from None


def _raw_layout(path: Path, header: dict[str, str], codes: np.ndarray) -> CsvTrace:
    if not np.all(codes == np.round(codes)):
        raise DataError(f"{path}: raw-sample rows must be integer codes")
    scale = _header_number(path, header, "Vertical Scale")
    period = _header_number(path, header, "Sampling Period")
    if scale <= 0 or not PERIOD_RANGE[0] <= period <= PERIOD_RANGE[1]:
        raise DataError(f"{path}: Vertical Scale {scale:g} must be positive and Sampling Period {period:g} s within "
                        f"{PERIOD_RANGE[0]:g}-{PERIOD_RANGE[1]:g} s")
    volts = codes * scale / COUNTS_PER_DIVISION
    t = np.arange(codes.size) * period
    return CsvTrace(path, t, volts, header, "raw",
                    {"volts_per_div": scale, "sampling_period_s": period, "source": header.get("Source")})


def _time_value_layout(path: Path, header: dict[str, str], rows: np.ndarray) -> CsvTrace:
    t_file, volts = rows[:, 0], rows[:, 1]
    n = t_file.size
    if n < 2 or not t_file[-1] > t_file[0]:
        raise DataError(f"{path}: time column does not increase")
    if "Sampling Period" in header:
        dt = _header_number(path, header, "Sampling Period")
    else:
        dt = (t_file[-1] - t_file[0]) / (n - 1)
    if not PERIOD_RANGE[0] <= dt <= PERIOD_RANGE[1]:
        raise DataError(f"{path}: sample interval {dt:g} s is not within {PERIOD_RANGE[0]:g}-{PERIOD_RANGE[1]:g} s")
    t = t_file[0] + np.arange(n) * dt
    # Printed times carry a few significant digits: allow half a step plus the print resolution.
    tolerance = 0.5 * dt + 1e-4 * float(np.max(np.abs(t_file)))
    worst = int(np.argmax(np.abs(t_file - t)))
    if abs(t_file[worst] - t[worst]) > tolerance:
        raise DataError(f"{path}: non-uniform time column (row {worst + 1}: {t_file[worst]:.6g} s, "
                        f"expected {t[worst]:.6g} s for a step of {dt:.6g} s)")
    return CsvTrace(path, t, volts, header, "time,value",
                    {"sampling_period_s": dt, "t0_s": float(t_file[0]), "source": header.get("Source")})
