"""Content keys for resuming: a fit is redone only when what it fits has changed.

key = SHA-256 over the mbus version, the canonical JSON of the resolved run config(s) (without
the ``output`` section, which does not change a fit), the replicate numbers and how replicates
are combined, followed by the SHA-256 of every input file the runs read (:func:`input_files`:
the record, a response channel, a waveform, a calibration; a run folder: every file in it, by
relative path). Upgrading mbus therefore refits.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Iterable

from mbus_framework import __version__
from mbus_framework.campaigns.paths import path_values
from mbus_framework.pipeline.input_files import digest

__all__ = ["content_key", "digest", "input_digests", "input_files"]


def content_key(configs: Iterable[dict[str, Any]], replicate_numbers: Iterable[int], mode: str,
                inputs: Iterable[tuple[str, str]]) -> str:
    """Hex SHA-256 of the mbus version, the configs and the ``(path, sha256)`` of their input files."""
    h = hashlib.sha256()
    canonical = {
        "mbus": __version__,
        "configs": [{k: v for k, v in c.items() if k != "output"} for c in configs],
        "replicates": [mode, list(replicate_numbers)],
    }
    h.update(json.dumps(canonical, sort_keys=True, separators=(",", ":"), default=str).encode())
    for path, digest in inputs:
        h.update(b"\0file\0" + Path(path).name.encode() + b"\0" + digest.encode())
    return h.hexdigest()


def input_files(configs: Iterable[dict[str, Any]]) -> list[Path]:
    """Absolute paths of the files (or run folders) the runs of ``configs`` read, without repeats
    (the campaign made every path option absolute: :mod:`~mbus_framework.campaigns.paths`)."""
    out: list[Path] = []
    for config in configs:
        for _, value in path_values(config):
            p = Path(value)
            if p not in out:
                out.append(p)
    return out


def input_digests(configs: Iterable[dict[str, Any]]) -> tuple[tuple[str, str], ...]:
    """``(absolute path, SHA-256 of its content)`` of every input file (``"missing"`` when absent)."""
    return tuple((str(p), digest(p)) for p in input_files(configs))
