"""Where analyses write, and JSON that survives numpy numbers and NaN."""
from __future__ import annotations

import json
import math
from pathlib import Path

from mbus_framework.errors import DataError
from mbus_framework.pipeline.storage import atomic_write_text, to_jsonable


def output_dir(table: str | Path, out: str | Path | None, default_name: str) -> Path:
    """``out`` or ``<table's folder>/<default_name>``, created."""
    path = Path(out) if out else Path(table).resolve().parent / default_name
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataError(f"{path}: cannot create the output folder ({exc.strerror})") from None
    return path


def _standard(obj):
    """NaN and infinities -> None (standard JSON), recursively."""
    if isinstance(obj, dict):
        return {k: _standard(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_standard(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


#: documents larger than this (bytes, compact) are written without indentation: the indenting
#: encoder is pure Python and takes seconds on the per-sample assignments of a 10,000-row table
COMPACT_ABOVE = 1_000_000


def _numpy_default(obj):
    import numpy as np

    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(type(obj).__name__)


def write_json(path: str | Path, data) -> Path:
    """Write ``data`` as standard JSON (numpy converted, NaN -> null), atomically: indented,
    or compact when larger than ``COMPACT_ABOVE`` bytes."""
    try:  # the C encoder: fast, refuses NaN and unknown types
        text = json.dumps(data, default=_numpy_default, allow_nan=False)
    except (TypeError, ValueError):
        text = None
    if text is None or len(text) <= COMPACT_ABOVE:
        text = json.dumps(_standard(to_jsonable(data)), indent=2, allow_nan=False)
    return atomic_write_text(path, text + "\n")
