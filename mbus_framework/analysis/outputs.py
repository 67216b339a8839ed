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


def write_json(path: str | Path, data) -> Path:
    """Write ``data`` as indented standard JSON (numpy converted, NaN -> null), atomically."""
    text = json.dumps(_standard(to_jsonable(data)), indent=2, allow_nan=False) + "\n"
    return atomic_write_text(path, text)
