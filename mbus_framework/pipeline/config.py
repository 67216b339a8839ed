"""Run configuration: safe YAML loading, ``--set`` overrides, two-stage validation.

Stage 1 checks the core structure (:class:`RunConfig`); stage 2 validates each plugin's
own ``options`` against that plugin's ``Options`` model (:func:`validate_options`). Errors
are :class:`~mbus_framework.errors.ConfigError` with one line naming the file and the key
path, with a 'did you mean' for misspelt keys.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, ValidationError, field_validator

from mbus_framework.errors import ConfigError
from mbus_framework.suggest import did_you_mean


class ConfigLoader(yaml.SafeLoader):
    """Safe loader that also reads 1e-6 and 6.0e8 as floats (YAML 1.1 wants 1.0e-6, 6.0e+8)."""


ConfigLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)


def yaml_load(text: str):
    """Parse YAML text with :class:`ConfigLoader` (safe: no Python object tags)."""
    return yaml.load(text, Loader=ConfigLoader)  # noqa: S506 - ConfigLoader is a SafeLoader


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class SampleConfig(_Strict):
    """``sample``: the pressure-wave column."""

    length: PositiveFloat = Field(description="sample thickness L [m]")
    diameter: PositiveFloat = Field(description="transducer element diameter D [m]")
    density: PositiveFloat = Field(description="density rho [kg/m^3]")


class PluginRef(_Strict):
    """A plugin chosen by name with its own options."""

    name: str
    options: dict[str, Any] = Field(default_factory=dict)

    @field_validator("options", mode="before")
    @classmethod
    def _empty_means_none(cls, value):
        return {} if value is None else value  # `options:` with every option commented out


class CompensatorRef(PluginRef):
    """``compensator``: optional; ``name`` defaults to ``none``."""

    name: str = "none"


class SolverRef(PluginRef):
    """``solver``: optional; ``name`` defaults to ``scipy_lm``."""

    name: str = "scipy_lm"


class ModelConfig(PluginRef):
    """``model``: the medium model to fit."""

    initial: dict[str, float] | None = Field(None, description="initial parameters (or properties)")
    fixed: dict[str, float] = Field(default_factory=dict, description="parameters held at these values")

    @field_validator("fixed", mode="before")
    @classmethod
    def _empty_fixed(cls, value):
        return {} if value is None else value
    hold: Literal["zoh", "foh"] = Field("zoh", description="input hold between samples")


class NuisanceValue(_Strict):
    """One nuisance parameter: its value (initial when estimated) and whether to estimate it."""

    estimate: bool = False
    value: float | None = None


class NuisanceConfig(_Strict):
    """``nuisance``: rig parameters that are not material properties."""

    input_gain: NuisanceValue = Field(
        default_factory=NuisanceValue, description="force per recorded input unit [N/unit], default 1"
    )
    delay: NuisanceValue = Field(default_factory=NuisanceValue, description="trigger offset [s], default 0")
    max_delay: PositiveFloat | None = Field(None, description="upper bound of the delay [s] (default: half the record)")


class IdentifiabilityConfig(_Strict):
    """``identifiability``: when the run warns instead of printing confident numbers."""

    max_correlation: float = Field(0.95, gt=0, le=1, description="|correlation| above this is flagged")
    max_relative_se: float = Field(0.5, gt=0, description="standard error / |estimate| above this is flagged")
    max_residual_autocorrelation: float = Field(
        0.2, gt=0, description="mean |autocorrelation| of residuals (lags 1-10) above this is flagged as misfit"
    )
    min_explained_variance: float = Field(
        0.25, ge=0, lt=1, description="a fit explaining less of the record's variance marks every parameter unreliable"
    )


class UncertaintyConfig(_Strict):
    """``uncertainty``: what the run computes besides the linearised intervals."""

    profile: bool = Field(False, description="also compute profile-likelihood intervals (one local fit per point)")
    level: float = Field(0.95, gt=0, lt=1, description="confidence level of the profile intervals")
    profile_tolerance: float = Field(
        0.25, gt=0, description="flag a profile interval whose ends differ from the linearised ones by more than "
        "this fraction of the linearised half-width")


class OutputConfig(_Strict):
    """``output``: where and what to write."""

    directory: str = Field("runs", description="parent of timestamped run folders (relative to the CWD)")
    plots: bool = Field(True, description="write PNG figures")


class RunConfig(_Strict):
    """One identification run."""

    title: str | None = None
    sample: SampleConfig
    model: ModelConfig
    excitation: PluginRef | None = Field(
        None, description="designed input; optional when the backend reads the recorded input (file backend)"
    )
    backend: PluginRef
    compensator: CompensatorRef = Field(default_factory=CompensatorRef)
    solver: SolverRef = Field(default_factory=SolverRef)
    nuisance: NuisanceConfig = Field(default_factory=NuisanceConfig)
    identifiability: IdentifiabilityConfig = Field(default_factory=IdentifiabilityConfig)
    uncertainty: UncertaintyConfig = Field(default_factory=UncertaintyConfig)
    calibration: dict[str, Any] | None = Field(
        None, description="makes the run a transducer calibration (see mbus_framework.studies.transducer_calibration)"
    )
    design: dict[str, Any] | None = Field(
        None, description="options of --design-excitation (see mbus_framework.studies.design)"
    )
    output: OutputConfig = Field(default_factory=OutputConfig)


def read_yaml(path: str | Path) -> dict[str, Any]:
    """Safe-load a YAML mapping from ``path``."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except (IsADirectoryError, PermissionError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read config ({type(exc).__name__})") from None
    try:
        data = yaml_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{path}: invalid YAML{where}: {problem}") from None
    if data is None:
        raise ConfigError(f"{path}: config file is empty")
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: top level must be a mapping of sections, not {type(data).__name__}")
    return data


def apply_overrides(data: dict[str, Any], overrides: list[str], where: str = "--set") -> dict[str, Any]:
    """Apply ``dotted.key=value`` overrides (value parsed as YAML) to a copy of ``data``."""
    import copy

    out = copy.deepcopy(data)
    for item in overrides:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key or any(not part for part in key.split(".")):
            raise ConfigError(f"{where} '{item}': expected dotted.key=value")
        try:
            value = yaml_load(text) if text.strip() else ""
        except yaml.YAMLError:
            value = text
        node = out
        parts = key.split(".")
        for i, part in enumerate(parts[:-1]):
            child = node.get(part)
            if child is None:
                child = node[part] = {}
            if not isinstance(child, dict):
                raise ConfigError(f"{where} '{item}': '{'.'.join(parts[: i + 1])}' is not a section")
            node = child
        node[parts[-1]] = value
    return out


def load_config(path: str | Path, overrides: list[str] | None = None) -> RunConfig:
    """Read, override and validate (stage 1) a run config."""
    data = apply_overrides(read_yaml(path), overrides or [])
    return validate_structure(data, str(path))


def validate_structure(data: dict[str, Any], source: str = "<config>") -> RunConfig:
    try:
        return RunConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{source}: {format_validation_error(exc, RunConfig)}") from None


def validate_options(options_model: type[BaseModel], options: Any, where: str, source: str | None = None):
    """Stage 2: validate a plugin's ``options`` mapping; errors name ``where`` (a key path)."""
    if options is None:
        options = {}
    if not isinstance(options, dict):
        prefix = f"{source}: " if source else ""
        raise ConfigError(f"{prefix}{where}: must be a mapping, not {type(options).__name__}")
    try:
        return options_model.model_validate(options)
    except ValidationError as exc:
        prefix = f"{source}: " if source else ""
        raise ConfigError(f"{prefix}{format_validation_error(exc, options_model, where)}") from None


def format_validation_error(exc: ValidationError, root: type[BaseModel], prefix: str = "") -> str:
    """One line for the first error: key path, problem, offending value, suggestion."""
    # A misspelt key shows up twice (unknown key + missing key); the unknown key explains both.
    errors = sorted(exc.errors(), key=lambda e: e["type"] != "extra_forbidden")
    err = errors[0]
    loc = [str(p) for p in err["loc"]]
    path = ".".join([prefix] * bool(prefix) + loc)
    more = f" (and {len(errors) - 1} more problem{'s' * (len(errors) > 2)})" if len(errors) > 1 else ""
    kind = err["type"]
    if kind == "extra_forbidden":
        choices = _field_names(root, err["loc"][:-1])
        return f"{path}: unknown key{did_you_mean(loc[-1], choices)}; allowed: {', '.join(choices)}{more}"
    if kind == "missing":
        return f"{path}: required key is missing{more}"
    got = err.get("input")
    shown = "" if isinstance(got, (dict, list)) else f" (got {got!r})"
    msg = err["msg"]
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    return f"{path}: {msg}{shown}{more}"


def _field_names(root: type[BaseModel], loc: tuple) -> list[str]:
    cls: Any = root
    for part in loc:
        field = getattr(cls, "model_fields", {}).get(part)
        if field is None:
            return []
        cls = _model_in(field.annotation)
        if cls is None:
            return []
    return list(getattr(cls, "model_fields", {}))


def _model_in(annotation: Any) -> type[BaseModel] | None:
    import typing

    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in typing.get_args(annotation):
        found = _model_in(arg)
        if found is not None:
            return found
    return None
