"""The campaign file: a ``campaign:`` mapping naming a base run config and a sample sheet
(docs/campaign-format.md)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from mbus_framework.campaigns.problems import CampaignError, Problems
from mbus_framework.campaigns.sheet import SheetRow, read_sheet
from mbus_framework.errors import ConfigError
from mbus_framework.pipeline.config import apply_overrides, format_validation_error, read_yaml
from mbus_framework.suggest import did_you_mean

CAMPAIGN_KEY = "campaign"


class CampaignSpec(BaseModel):
    """The ``campaign:`` mapping."""

    model_config = ConfigDict(extra="forbid")

    title: str | None = None
    base: str | None = Field(None, description="run config file, relative to the campaign file")
    run: dict[str, Any] | None = Field(None, description="the run config inline (instead of base)")
    samples: str | list[Any] = Field(description="sample sheet: CSV path (relative to the campaign file) or a list")
    groups: list[str] = Field(default_factory=list, description="group-label columns")
    covariates: list[str] = Field(default_factory=list, description="columns carried into the table untouched")
    replicates: Literal["auto", "average", "joint", "fit"] = Field(
        "auto", description="average: average a sample's replicate records, one fit; joint: fit them jointly "
                            "(shared properties, per-replicate input gain and delay); auto: joint where the "
                            "replicates differ in gain or delay, else average; fit: fit each replicate"
    )
    scheduler: str | None = Field(None, description="Dask scheduler address (tcp://host:8786); null = LocalCluster")
    workers: int | None = Field(None, ge=1, description="LocalCluster worker processes; null = one per core")
    timeout: float | None = Field(None, gt=0, description="seconds to wait for the scheduler and its first worker; null = 15")

    @model_validator(mode="after")
    def _one_config(self):
        if (self.base is None) == (self.run is None):
            raise ValueError("give exactly one of 'base' (a run config file) and 'run' (the run config inline)")
        return self


@dataclass
class Campaign:
    """A parsed campaign: its spec, the base run config (``--set`` overrides applied) and the rows."""

    path: Path
    spec: CampaignSpec
    base: dict[str, Any]
    base_source: Path
    rows: list[SheetRow]

    @property
    def name(self) -> str:
        return self.path.stem

    @property
    def title(self) -> str:
        return self.spec.title or self.base.get("title") or self.name


def is_campaign_file(path: str | Path) -> bool:
    """True when ``path`` is a YAML mapping with a top-level ``campaign:`` key."""
    p = Path(path)
    if p.suffix.lower() not in (".yaml", ".yml") or not p.is_file():
        return False
    try:
        return CAMPAIGN_KEY in read_yaml(p)
    except ConfigError:
        return False


def load_campaign(path: str | Path, overrides: list[str] | None = None, problems: Problems | None = None) -> Campaign:
    """Read a campaign file and its sheet; every problem found is reported at once
    (:class:`CampaignError`, one line each). With ``problems`` given, problems of the sheet's
    rows are added there (those rows left out) for the caller to report with its own."""
    path = Path(path)
    data = read_yaml(path)
    collect = problems is not None
    problems = problems if collect else Problems()
    for key in data:
        if key != CAMPAIGN_KEY:
            problems.add(f"{path}: {key}: unknown top-level key{did_you_mean(key, [CAMPAIGN_KEY])}; a campaign "
                         f"file holds one '{CAMPAIGN_KEY}:' mapping")
    raw = data.get(CAMPAIGN_KEY)
    if not isinstance(raw, dict):
        problems.add(f"{path}: {CAMPAIGN_KEY}: must be a mapping (see docs/campaign-format.md)")
        problems.raise_if_any()
    try:
        spec = CampaignSpec.model_validate(raw)
    except ValidationError as exc:
        problems.add(f"{path}: {format_validation_error(exc, CampaignSpec, CAMPAIGN_KEY)}")
        problems.raise_if_any()
    if spec.base is not None:
        base_source = path.parent / spec.base
        try:
            base = read_yaml(base_source)
        except ConfigError as exc:
            problems.add(f"{path}: campaign.base: {exc}")
            base = {}
    else:
        base_source, base = path, dict(spec.run or {})
    try:
        base = apply_overrides(base, overrides or [])
    except ConfigError as exc:
        problems.add(str(exc))
    rows = read_sheet(spec.samples, path, spec.groups, spec.covariates, problems)
    if not collect or not rows:
        problems.raise_if_any()
    return Campaign(path, spec, base, base_source, rows)
