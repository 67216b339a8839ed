"""Reading instrument exports whose CSV headers carry units: ``force [N]``, ``E' (kPa)``.

A header is ``name``, ``name [unit]`` or ``name (unit)``; a name without a unit is taken in
SI (s, N, m, Hz, Pa, Pa s). Values are converted to SI on reading, so a texture-analyser
export in ``g`` and ``mm`` and a rheometer export in ``rad/s`` and ``kPa`` need no editing.
Unknown units, missing columns, text in a numeric column and empty cells are one-line
:class:`~mbus_framework.errors.DataError` messages naming the file, column and line.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from mbus_framework.errors import DataError

STANDARD_GRAVITY = 9.80665  # m/s^2, for gram-force and kilogram-force

#: dimension -> unit spelling -> factor to SI
UNITS: dict[str, dict[str, float]] = {
    "time": {"s": 1.0, "ms": 1e-3, "min": 60.0},
    "force": {"N": 1.0, "kN": 1e3, "mN": 1e-3, "g": 1e-3 * STANDARD_GRAVITY, "gf": 1e-3 * STANDARD_GRAVITY,
              "kg": STANDARD_GRAVITY, "kgf": STANDARD_GRAVITY},
    "length": {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6},
    "area": {"m^2": 1.0, "cm^2": 1e-4, "mm^2": 1e-6, "m2": 1.0, "cm2": 1e-4, "mm2": 1e-6},
    "frequency": {"Hz": 1.0, "rad/s": 1.0 / (2.0 * math.pi)},
    "modulus": {"Pa": 1.0, "kPa": 1e3, "MPa": 1e6, "GPa": 1e9},
    "viscosity": {"Pa s": 1.0, "mPa s": 1e-3, "kPa s": 1e3, "MPa s": 1e6},
}

_HEADER = re.compile(r"^\s*(?P<name>.*?)\s*(?:[\[(](?P<unit>[^\])]*)[\])])?\s*$")


@dataclass(frozen=True)
class Quantity:
    """A column an export must (or may) have: canonical key, accepted names, dimension."""

    key: str
    names: tuple[str, ...]
    dimension: str
    required: bool = True
    #: unit assumed for a header name without one, when it is not SI (``omega`` -> ``rad/s``)
    implied_units: tuple[tuple[str, str], ...] = ()


def _normalise_unit(unit: str) -> str:
    unit = unit.strip().replace("²", "^2")
    return re.sub(r"\s*[.*·⋅]\s*|\s+", " ", unit)


def split_header(header: str) -> tuple[str, str | None]:
    """``"force [kN]"`` -> ``("force", "kN")``; ``"time"`` -> ``("time", None)``."""
    match = _HEADER.match(str(header))
    name, unit = match.group("name"), match.group("unit")
    return name.strip().lower(), (_normalise_unit(unit) if unit is not None else None)


def unit_factor(dimension: str, unit: str | None, where: str) -> float:
    """Factor converting ``unit`` of ``dimension`` to SI (None means SI already)."""
    if unit is None or unit == "":
        return 1.0
    table = UNITS[dimension]
    if unit in table:
        return table[unit]
    raise DataError(f"{where}: unknown {dimension} unit '{unit}' (choose one of: {', '.join(table)})")


def locate(columns: Iterable[str], quantities: Iterable[Quantity], source: str) -> dict[str, tuple[str, float]]:
    """Map each quantity's key to (column header, factor to SI); errors name what is missing."""
    parsed = {col: split_header(col) for col in columns}
    found: dict[str, tuple[str, float]] = {}
    for q in quantities:
        names = {n.lower() for n in q.names}
        hits = [col for col, (name, _) in parsed.items() if name in names]
        if len(hits) > 1:
            raise DataError(f"{source}: columns {', '.join(map(repr, hits))} all give {q.key}; keep one")
        if not hits:
            if q.required:
                have = ", ".join(map(repr, parsed)) or "none"
                raise DataError(f"{source}: no {q.key} column (expected one of: {', '.join(q.names)}; "
                                f"found: {have})")
            continue
        col = hits[0]
        name, unit = parsed[col]
        unit = unit if unit is not None else dict(q.implied_units).get(name)
        found[q.key] = (col, unit_factor(q.dimension, unit, f"{source}: column '{col}'"))
    return found


def read_export(path: str | Path, quantities: Iterable[Quantity]) -> dict[str, np.ndarray]:
    """Read a CSV/TSV export (``#`` comments, ``.gz`` allowed) -> {key: SI values}.

    Every row must hold a number in every located column.
    """
    import pandas as pd

    p = Path(path)
    quantities = list(quantities)
    if not p.is_file():
        raise DataError(f"{p}: file not found")
    try:
        frame = pd.read_csv(p, sep=None, engine="python", comment="#", skipinitialspace=True)
    except (OSError, ValueError, UnicodeDecodeError, pd.errors.ParserError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DataError(f"{p}: cannot read ({first[:200]})") from None
    where = locate(frame.columns, quantities, str(p))
    if frame.empty:
        raise DataError(f"{p}: no data rows")
    out: dict[str, np.ndarray] = {}
    for key, (col, factor) in where.items():
        values = pd.to_numeric(frame[col], errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            row = int(bad[0])
            raise DataError(f"{p}: column '{col}', data row {row + 1}: not a number ({frame[col].iloc[row]!r})")
        out[key] = values * factor
    return out
