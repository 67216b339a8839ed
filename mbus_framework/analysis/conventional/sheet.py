"""The conventional sheet: which record files belong to which sample, reduced per sample.

A CSV with one row per measured specimen (replicates are several rows with the same id):

| column | meaning |
|---|---|
| ``sample_id`` | the campaign's sample id (joins the campaign table) |
| ``test`` | ``compression`` (cyclic compression record) or ``rheometer`` (shear sweep table) |
| ``file`` | the record, path relative to the sheet |
| ``length``, ``diameter`` (or ``area``) | compression specimen geometry (SI, or a unit in the header: ``length [mm]``) |
| ``frequency`` | compression test frequency [Hz] |

Each sample's replicates are averaged into the columns that the calibration joins by
``sample_id`` (:data:`CONVENTIONAL`): ``conv_E_sigma`` and ``conv_eta_sigma`` (compression E,
eta), ``conv_E_tau`` and ``conv_eta_tau`` (rheometer E', eta' at the shear frequency), each
with ``_n`` (replicates), ``_sd`` (replicate standard deviation) and ``_se`` (SD / sqrt(n) for
two or more replicates; for one compression record, the standard error of its sinusoid fit).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from mbus_framework.errors import DataError
from mbus_framework.analysis.conventional.columns import Quantity, locate
from mbus_framework.analysis.conventional.compression import analyse_compression_file
from mbus_framework.analysis.conventional.rheometer import analyse_sweep_file

PREFIX = "conv_"
#: MBUS property -> (conventional test, value key, standard-error key) (Section 6.3)
CONVENTIONAL = {
    "E_sigma": ("compression", "E", "E_se"),
    "eta_sigma": ("compression", "eta", "eta_se"),
    "E_tau": ("rheometer", "storage_modulus", None),
    "eta_tau": ("rheometer", "dynamic_viscosity", None),
}
TESTS = ("compression", "rheometer")
_GEOMETRY = (
    Quantity("length", ("length",), "length", required=False),
    Quantity("diameter", ("diameter",), "length", required=False),
    Quantity("area", ("area",), "area", required=False),
    Quantity("frequency", ("frequency",), "frequency", required=False),
)


def read_sheet(path: str | Path):
    """The sheet as a DataFrame with SI ``length``, ``area`` and ``frequency`` columns."""
    import pandas as pd

    p = Path(path)
    if not p.is_file():
        raise DataError(f"{p}: conventional sheet not found")
    try:
        raw = pd.read_csv(p, comment="#", skipinitialspace=True, dtype={"sample_id": str})
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise DataError(f"{p}: cannot read conventional sheet ({str(exc).splitlines()[0][:200]})") from None
    for col in ("sample_id", "test", "file"):
        if col not in raw.columns:
            raise DataError(f"{p}: column '{col}' is missing (need sample_id, test, file)")
    geometry = locate(raw.columns, _GEOMETRY, str(p))
    known = {"sample_id", "test", "file", "replicate"} | {col for col, _ in geometry.values()}
    extra = [c for c in raw.columns if c not in known]
    if extra:
        raise DataError(f"{p}: unknown column(s) {', '.join(map(repr, extra))} "
                        "(allowed: sample_id, test, file, replicate, length, diameter, area, frequency)")
    sheet = pd.DataFrame({"sample_id": raw["sample_id"].astype(str).str.strip(),
                          "test": raw["test"].astype(str).str.strip().str.lower(),
                          "file": raw["file"].astype(str).str.strip()})
    for key in ("length", "diameter", "area", "frequency"):
        col, factor = geometry.get(key, (None, 1.0))
        sheet[key] = pd.to_numeric(raw[col], errors="coerce") * factor if col else np.nan
    sheet["area"] = sheet["area"].fillna(math.pi * sheet["diameter"] ** 2 / 4.0)
    for i, row in sheet.iterrows():
        where = f"{p}: row {i + 2}"
        if row.test not in TESTS:
            raise DataError(f"{where}, column 'test': '{row.test}' (choose one of: {', '.join(TESTS)})")
        if row.test == "compression":
            for key, label in (("length", "length"), ("area", "diameter or area"), ("frequency", "frequency")):
                if not (np.isfinite(row[key]) and row[key] > 0):
                    raise DataError(f"{where}: a compression row needs a positive {label}")
    sheet.attrs["source"] = str(p)
    return sheet


def reduce_records(sheet, base_dir: str | Path, *, shear_frequency: float = 10.0, skip_bad: bool = False,
                   **compression_options):
    """One row per record file with its reduced values; bad records raise or are skipped.

    Returns (records, problems): ``problems`` lists the one-line messages of skipped records
    (empty unless ``skip_bad``). Without ``skip_bad`` every bad record is reported in one
    DataError.
    """
    import pandas as pd

    base = Path(base_dir)
    rows, problems = [], []
    for _, row in sheet.iterrows():
        path = base / row.file
        try:
            if row.test == "compression":
                result = analyse_compression_file(path, frequency=float(row.frequency), length=float(row.length),
                                                  area=float(row.area), **compression_options)
            else:
                result = analyse_sweep_file(path, f0=shear_frequency)
        except DataError as exc:
            problems.append(str(exc))
            continue
        rows.append({"sample_id": row.sample_id, "test": row.test, "file": row.file, **result.as_dict()})
    if problems and not skip_bad:
        head = f"{len(problems)} of {len(sheet)} conventional records unusable: " if len(problems) > 1 else ""
        raise DataError(head + "; ".join(problems))
    return pd.DataFrame(rows), problems


def per_sample(records):
    """Average each sample's replicates into the ``conv_*`` columns (see module docstring)."""
    import pandas as pd

    out: dict[str, dict] = {}
    for prop, (test, key, se_key) in CONVENTIONAL.items():
        if records.empty or key not in records.columns:
            continue
        subset = records[records["test"] == test]
        for sample_id, grp in subset.groupby("sample_id", sort=False):
            values = grp[key].to_numpy(dtype=float)
            n = values.size
            sd = float(np.std(values, ddof=1)) if n > 1 else float("nan")
            if n > 1:
                se = sd / math.sqrt(n)
            else:
                se = float(grp[se_key].iloc[0]) if se_key else float("nan")
            out.setdefault(sample_id, {"sample_id": sample_id}).update({
                f"{PREFIX}{prop}": float(values.mean()), f"{PREFIX}{prop}_se": se,
                f"{PREFIX}{prop}_sd": sd, f"{PREFIX}{prop}_n": n})
    return pd.DataFrame(list(out.values()))


def conventional_table(path: str | Path, *, shear_frequency: float = 10.0, skip_bad: bool = False,
                       **compression_options):
    """(per-sample table, per-record table, skipped-record messages) of a conventional sheet."""
    sheet = read_sheet(path)
    records, problems = reduce_records(sheet, Path(path).parent, shear_frequency=shear_frequency,
                                       skip_bad=skip_bad, **compression_options)
    return per_sample(records), records, problems
