"""One rule for the file paths of a config: relative to where they were written.

A relative path written in a config file is taken from the config file's folder (not from the
working directory, so a run behaves the same wherever it is started); a relative path given with
``--set`` on the command line is taken from the working directory, where it was typed. Both
become absolute before the config is validated, so the run folder's ``config.yaml`` re-runs from
anywhere. An input file that is not there is a one-line error naming the config key, the value
and the place searched.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from mbus_framework.errors import DataError

INPUTS = {
    ("backend", "options", "path"): "file",
    ("backend", "options", "response_path"): "file",
    ("compensator", "options", "calibration"): "calibration file",
    ("excitation", "options", "path"): "waveform file",
}
"""Config keys that name files read by the run, with what each is."""

OUTPUTS = (("calibration", "output"),)
"""Config keys that name files the run writes."""


def _node(data: dict[str, Any], key: tuple[str, ...]) -> tuple[dict | None, Any]:
    node: Any = data
    for part in key[:-1]:
        node = node.get(part) if isinstance(node, dict) else None
    if not isinstance(node, dict):
        return None, None
    return node, node.get(key[-1])


def resolve(file_data: dict[str, Any], data: dict[str, Any], config_path: Path, source: str,
            check: bool = True) -> dict[str, Any]:
    """``data`` (the config after ``--set``) with absolute paths: values as written in the file
    (``file_data``) relative to its folder, values changed by ``--set`` relative to the working
    directory (``~`` expanded); with ``check``, an input file that does not exist is a one-line
    DataError naming the key, the value and the place searched.
    ``data`` is changed in place and returned."""
    folder = config_path.parent.absolute()
    for key in (*INPUTS, *OUTPUTS):
        node, value = _node(data, key)
        if node is None or not isinstance(value, str) or not value.strip():
            continue
        from_file = value == _node(file_data, key)[1]
        base = folder if from_file else Path.cwd()
        path = Path(os.path.expanduser(value.strip()))
        resolved = path if path.is_absolute() else base / path
        node[key[-1]] = str(resolved)
        if check and key in INPUTS and not resolved.exists():
            rule = "" if path.is_absolute() else (
                f" (a relative path is taken from the config file's folder, {folder})" if from_file
                else f" (a relative --set path is taken from the working directory, {base})")
            raise DataError(f"{source}: {'.'.join(key)} = {value!r}: {resolved}: {INPUTS[key]} not found{rule}")
    return data
