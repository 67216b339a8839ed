"""Input paths of a campaign, resolved once on the client and made absolute.

A worker of a real cluster runs in its own current directory, so a relative path in a task
could name another file there. Before a task leaves, every path option a run reads
(:data:`PATH_KEYS`) is made absolute: a path from the base config against the base config's
folder, a path from the sample sheet against the sheet's folder (as given, relative to the
client's current directory, only when it is not there but is here).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterator

#: (section, option) of the run config whose string value is a file or folder that a run reads:
#: the file backend's record and response channel, a from_file excitation's waveform and the
#: transfer-function compensator's calibration.
PATH_KEYS = (
    ("backend", "path"),
    ("backend", "response_path"),
    ("excitation", "path"),
    ("compensator", "calibration"),
)


def absolute(name: str, folder: Path) -> str:
    """``name`` as an absolute path: as given if absolute; else next to ``folder`` when it is
    there (or is in neither place), else relative to the current directory."""
    p = Path(name).expanduser()
    if p.is_absolute():
        return str(p)
    beside = folder / p
    if beside.exists() or not p.exists():
        return str(beside.resolve())
    return str(p.resolve())


def _options(config: dict[str, Any], section: str) -> dict[str, Any] | None:
    part = config.get(section)
    options = part.get("options") if isinstance(part, dict) else None
    return options if isinstance(options, dict) else None


def path_values(config: dict[str, Any]) -> Iterator[tuple[str, str]]:
    """``(dotted key, value)`` of every path option set in ``config``."""
    for section, key in PATH_KEYS:
        options = _options(config, section)
        if options is not None and isinstance(options.get(key), str) and options[key]:
            yield f"{section}.options.{key}", options[key]


def resolve_paths(config: dict[str, Any], folder: Path, unchanged_from: dict[str, Any] | None = None) -> dict[str, Any]:
    """``config`` (changed in place and returned) with every path option made absolute against
    ``folder``; values equal to those in ``unchanged_from`` (already resolved) are kept."""
    before = dict(path_values(unchanged_from)) if unchanged_from is not None else {}
    for section, key in PATH_KEYS:
        options = _options(config, section)
        value = options.get(key) if options is not None else None
        if isinstance(value, str) and value and before.get(f"{section}.options.{key}") != value:
            options[key] = absolute(value, folder)
    return config
