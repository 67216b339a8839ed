"""Provenance of a run's input files: the absolute path and SHA-256 of each file a config names
(``backend.options.path``, ``response_path``, a calibration, a waveform file), recorded in the
run folder's ``measurement.json`` as ``inputs: [{key, path, sha256}]`` (the key campaigns use).
A folder (a lab run, a run folder) is hashed over every file in it, by relative path."""
from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any, Mapping

from mbus_framework.pipeline.config_paths import INPUTS

_CHUNK = 1 << 20


def digest(path: str | Path) -> str:
    """Hex SHA-256 of a file, of a folder (every file in it, by relative path), or ``"missing"``."""
    path = Path(path)
    h = hashlib.sha256()
    if path.is_dir():
        for f in sorted(p for p in path.rglob("*") if p.is_file()):
            h.update(b"\0member\0" + str(f.relative_to(path)).encode())
            _update_with_file(h, f)
    elif path.is_file():
        _update_with_file(h, path)
    else:
        return "missing"
    return h.hexdigest()


def _update_with_file(h, path: Path) -> None:
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            h.update(chunk)


def input_files(config: Mapping[str, Any]) -> list[dict[str, str]]:
    """[{key, path (absolute), sha256}] of every input file the config (a mapping) names."""
    out = []
    for key in INPUTS:
        node: Any = config
        for part in key:
            node = node.get(part) if isinstance(node, Mapping) else None
        if isinstance(node, str) and node.strip():
            path = Path(node).resolve()
            out.append({"key": ".".join(key), "path": str(path), "sha256": digest(path)})
    return out
