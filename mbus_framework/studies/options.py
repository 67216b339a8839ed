"""Study options: one pydantic model per kind, parsed from ``--study-option key=value``."""
from __future__ import annotations

from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from mbus_framework.errors import ConfigError
from mbus_framework.pipeline.config import format_validation_error

KINDS = ("monte_carlo", "element_sweep", "repeatability")


# ---------------------------------------------------------------------------------------
# Options
# ---------------------------------------------------------------------------------------
class _Options(BaseModel):
    model_config = ConfigDict(extra="forbid")
    keep_runs: bool = Field(False, description="keep every run's whole folder (waveforms too), not only result.json")


class MonteCarloOptions(_Options):
    n_runs: int = Field(50, ge=2, description="number of noise seeds")
    first_seed: int | None = Field(None, description="first seed (default: the config's backend.options.seed)")
    coverage_interval_level: float = Field(
        0.95, gt=0, lt=1,
        description="confidence level of the Clopper-Pearson interval around each measured coverage "
        "(the runs' own intervals are always 95 %)",
    )


class ElementSweepOptions(_Options):
    n_values: list[int] = Field(
        default_factory=lambda: [2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 25, 30, 35, 40],
        description="element counts; a list, 'a..b' (every n), 'a..b:step' or 'a,b,c'",
    )
    reference_n: int | None = Field(
        40, ge=1, le=400,
        description="simulated rig without its own medium: data from this many elements of the config's "
        "true medium (null: the config's own backend, unchanged)",
    )
    tolerance: float = Field(0.02, gt=0, description="settled: every later estimate within this relative change")
    warm_start: bool = Field(
        True,
        description="also fit each n from its finer neighbour's estimate (a second pass, finest first) and keep "
        "the lower cost: a coarse chain cannot match the fine medium, and its cost has more local minima",
    )

    @field_validator("n_values", mode="before")
    @classmethod
    def _parse_n_values(cls, value):
        return parse_int_list(value)

    @field_validator("n_values")
    @classmethod
    def _check_n_values(cls, value):
        if len(value) < 2:
            raise ValueError("give at least two element counts")
        if min(value) < 1:
            raise ValueError("element counts must be >= 1")
        return sorted(set(value))


class RepeatabilityOptions(_Options):
    n_runs: int = Field(5, ge=2, description="number of excitation realisations")
    vary: Literal["auto", "shift", "seed", "shift+seed"] = Field(
        "auto",
        description="what differs between runs: the PRBS start (excitation.options.shift), the noise seed, "
        "or both (auto: shift, plus the seed on a rig that has one)",
    )
    shift_step: int | None = Field(None, ge=1, description="bits between realisations (default: period / n_runs)")
    first_seed: int | None = Field(None, description="first noise seed (default: the config's)")


OPTIONS: dict[str, type[_Options]] = {
    "monte_carlo": MonteCarloOptions,
    "element_sweep": ElementSweepOptions,
    "repeatability": RepeatabilityOptions,
}


def parse_int_list(value: Any) -> list[int]:
    """``[2, 4]``, ``8``, ``"2..40"``, ``"2..40:2"``, ``"2,4,8"`` -> list of ints."""
    if isinstance(value, bool):
        raise ValueError("expected integers")
    if isinstance(value, int):
        return [value]
    if isinstance(value, (list, tuple)):
        out = []
        for v in value:
            if isinstance(v, bool) or not isinstance(v, int):
                raise ValueError(f"expected integers, got {v!r}")
            out.append(int(v))
        return out
    if isinstance(value, str):
        text = value.strip().strip("[]")
        try:
            if ".." in text:
                span, _, step = text.partition(":")
                a, _, b = span.partition("..")
                a, b, s = int(a), int(b), int(step) if step else 1
                if s < 1 or b < a:
                    raise ValueError
                return list(range(a, b + 1, s))
            return [int(p) for p in text.replace(" ", ",").split(",") if p]
        except ValueError:
            raise ValueError(f"cannot read element counts from {value!r}; use e.g. 2..40, 2..40:2 or 2,4,8") from None
    raise ValueError(f"expected a list of integers, got {type(value).__name__}")


def parse_study_options(items: list[str] | None) -> dict[str, Any]:
    """``["n_runs=50", "n_values=2..40"]`` -> ``{"n_runs": 50, "n_values": "2..40"}``.

    Values are read as YAML (numbers, booleans, lists ``[2, 4]``, null); a later key
    replaces an earlier one. Raises :class:`ConfigError` naming the bad item.
    """
    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, text = str(item).partition("=")
        key = key.strip()
        if not sep or not key or not key.replace("_", "").isalnum():
            raise ConfigError(f"--study-option '{item}': expected key=value, e.g. n_runs=50")
        try:
            value = yaml.safe_load(text) if text.strip() else ""
        except yaml.YAMLError:
            value = text
        out[key] = value
    return out


def validate_study_options(kind: str, options: dict[str, Any]):
    if kind not in OPTIONS:
        from mbus_framework.suggest import did_you_mean

        raise ConfigError(f"unknown study '{kind}'{did_you_mean(kind, KINDS)}; choose one of: {', '.join(KINDS)}")
    try:
        return OPTIONS[kind].model_validate(options)
    except ValidationError as exc:
        raise ConfigError(f"study {kind}: {format_validation_error(exc, OPTIONS[kind], 'option')}") from None
