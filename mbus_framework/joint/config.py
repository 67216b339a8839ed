"""A joint config: one run config (the base) plus a ``joint`` section listing the records.

    joint:
      shared: [E_sigma, eta_sigma, E_tau, eta_tau]   # default: every property not per record
      per_record: [input_gain]                       # per-record properties and nuisance parameters
      records:                                       # each: a label and the sections it changes
        - label: 2 cm slice
          sample: {length: 0.02}
          backend: {options: {input_gain: 1.6, seed: 11}}

Each record's config is the base with the record's sections merged in (mappings key by key),
validated as a run config; errors name ``joint.records[i]``.
"""
from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from mbus_framework.errors import ConfigError

KEY = "joint"


class JointSection(BaseModel):
    """The ``joint`` section."""

    model_config = ConfigDict(extra="forbid")
    shared: list[str] | None = Field(None, description="property names shared by all records")
    per_record: list[str] = Field(default_factory=list, description="properties and nuisance parameters per record")
    records: list[dict[str, Any]] = Field(min_length=1, description="per record: label and changed sections")


def is_joint_file(path: str | Path) -> bool:
    """A YAML file with a top-level ``joint`` section."""
    from mbus_framework.pipeline.config import config_mapping_or_none

    data = config_mapping_or_none(path)
    return data is not None and KEY in data


def merge(base: dict[str, Any], change: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``change`` merged in: mappings key by key, anything else replaced."""
    out = copy.deepcopy(base)
    for key, value in change.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def split(data: dict[str, Any], source: str) -> tuple[JointSection, dict[str, Any], list[tuple[str, dict[str, Any]]]]:
    """(joint section, base config, [(label, record config)]) of a joint config mapping."""
    from mbus_framework.pipeline.config import format_validation_error

    raw = data.get(KEY)
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: {KEY}: must be a mapping with shared, per_record and records")
    try:
        section = JointSection.model_validate(raw)
    except ValidationError as exc:
        raise ConfigError(f"{source}: {format_validation_error(exc, JointSection, KEY)}") from None
    base = {k: v for k, v in data.items() if k != KEY}
    records = []
    for i, rec in enumerate(section.records):
        label = rec.get("label", f"record {i + 1}")
        if not isinstance(label, str) or not label.strip():
            raise ConfigError(f"{source}: {KEY}.records[{i}].label: must be a non-empty text")
        change = {k: v for k, v in rec.items() if k != "label"}
        if KEY in change:
            raise ConfigError(f"{source}: {KEY}.records[{i}].{KEY}: a record cannot hold a joint section")
        records.append((label, merge(base, change)))
    labels = [lab for lab, _ in records]
    for i, lab in enumerate(labels):
        if lab in labels[:i]:
            raise ConfigError(f"{source}: {KEY}.records[{i}].label: {lab!r} is used twice")
    return section, base, records
