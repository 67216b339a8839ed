"""Content keys for resuming: a fit is redone only when what it fits has changed.

key = SHA-256 over the canonical JSON of the resolved run config(s) (without the ``output``
section, which does not change a fit), the replicate numbers and how replicates are combined,
followed by the bytes of every data file the file backend reads (a run folder: every file in
it, by relative path). The package version is not part of the key.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Iterable

_CHUNK = 1 << 20


def content_key(configs: Iterable[dict[str, Any]], replicate_numbers: Iterable[int], mode: str, source: str) -> str:
    """Hex SHA-256 of the configs and the data files they read (see the module docstring)."""
    configs = list(configs)
    h = hashlib.sha256()
    canonical = {
        "configs": [{k: v for k, v in c.items() if k != "output"} for c in configs],
        "replicates": [mode, list(replicate_numbers)],
    }
    h.update(json.dumps(canonical, sort_keys=True, separators=(",", ":"), default=str).encode())
    for path in data_files(configs, source):
        h.update(b"\0file\0" + str(path.name).encode())
        _update_with_path(h, path)
    return h.hexdigest()


def data_files(configs: Iterable[dict[str, Any]], source: str) -> list[Path]:
    """Files read by a ``file`` backend in ``configs``, resolved as the backend resolves them
    (as given, else relative to the folder of ``source``)."""
    out: list[Path] = []
    for config in configs:
        backend = config.get("backend") or {}
        if backend.get("name") != "file":
            continue
        options = backend.get("options") or {}
        for key in ("path", "response_path"):
            if options.get(key):
                p = Path(options[key])
                if not p.is_absolute() and not p.exists():
                    p = Path(source).parent / p
                out.append(p)
    return out


def _update_with_path(h, path: Path) -> None:
    if path.is_dir():
        for f in sorted(p for p in path.rglob("*") if p.is_file()):
            h.update(b"\0member\0" + str(f.relative_to(path)).encode())
            _update_with_file(h, f)
    elif path.is_file():
        _update_with_file(h, path)
    else:
        h.update(b"\0missing\0")


def _update_with_file(h, path: Path) -> None:
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            h.update(chunk)
