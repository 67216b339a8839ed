"""Where analyses write, and JSON that survives numpy numbers and NaN."""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from mbus_framework.errors import DataError


def output_dir(table: str | Path, out: str | Path | None, default_name: str) -> Path:
    """``out`` or ``<table's folder>/<default_name>``, created."""
    path = Path(out) if out else Path(table).resolve().parent / default_name
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataError(f"{path}: cannot create the output folder ({exc.strerror})") from None
    return path


def to_jsonable(obj):
    """Plain Python for JSON: numpy scalars and arrays converted, NaN and infinities -> None."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        value = float(obj)
        return value if math.isfinite(value) else None
    return obj


def write_json(path: str | Path, data) -> Path:
    """Write ``data`` as indented JSON, atomically (temporary file, then rename)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(to_jsonable(data), indent=2, allow_nan=False) + "\n")
    os.replace(tmp, path)
    return path
