"""Run configuration: safe, bounded YAML loading, ``--set`` overrides, two-stage validation.

Stage 1 checks the core structure (:class:`RunConfig`); stage 2 validates each plugin's
own ``options`` against that plugin's ``Options`` model (:func:`validate_options`). Errors
are :class:`~mbus_framework.errors.ConfigError` with one line naming the file and the key
path, with a 'did you mean' for misspelt keys.

Every number anywhere in a config must be finite (``.nan``, ``.inf`` and ``1e400`` are refused
with their key path), and the sample's dimensions must be physically possible; the YAML
itself is bounded in size, depth and alias expansion (:mod:`mbus_framework.pipeline.yaml_loader`).
"""
from __future__ import annotations

import copy
import functools
import math
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, ValidationError, field_validator

from mbus_framework.errors import ConfigError, shown
from mbus_framework.pipeline.yaml_loader import (  # noqa: F401 - yaml_load, ConfigLoader: public names
    ConfigLoader,
    LimitError,
    describe_yaml_error,
    read_config_text,
    yaml_load,
)
from mbus_framework.suggest import did_you_mean


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


SAMPLE_RANGES = {
    "length": (1e-6, 10.0, "m", "no sample between two transducer faces is thinner than 1 um or longer than 10 m"),
    "diameter": (1e-5, 10.0, "m", "transducer elements span 10 um to metres"),
    "density": (1e-2, 1e5, "kg/m^3", "from a gas at low pressure to beyond osmium's 22,590 kg/m^3"),
}


class SampleConfig(_Strict):
    """``sample``: the pressure-wave column (ranges: :data:`SAMPLE_RANGES`)."""

    length: PositiveFloat = Field(description="sample thickness L [m]")
    diameter: PositiveFloat = Field(description="transducer element diameter D [m]")
    density: PositiveFloat = Field(description="density rho [kg/m^3]")

    @field_validator("length", "diameter", "density")
    @classmethod
    def _physical(cls, value: float, info):
        lo, hi, unit, reason = SAMPLE_RANGES[info.field_name]
        if not lo <= value <= hi:
            raise ValueError(f"{value:g} {unit} is outside [{lo:g}, {hi:g}] {unit} ({reason})")
        return value


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
    """``model``: the medium model to fit; optional, ``name`` defaults to ``kelvin_voigt`` (as
    the Python API's ``fit``)."""

    name: str = "kelvin_voigt"

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

    max_correlation: float = Field(0.95, gt=0, le=1, description="|correlation| above which parameters form a "
                                   "correlated group (reported; warned only when the group is also imprecise)")
    precise_relative_se: float = Field(
        0.05, gt=0, description="standard error / |estimate| below which a parameter is precise: a correlated group "
        "warns only when a member exceeds it, and a fit whose parameters are all below it at a signal-to-noise of 10 "
        "or more passes the information gate")
    max_relative_se: float = Field(0.2, gt=0, description="standard error / |estimate| above this is flagged")
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


class EstimationConfig(_Strict):
    """``estimation``: which part of the record is fitted (:mod:`mbus_framework.pipeline.reduction`)."""

    decimate: int = Field(1, ge=1, le=1000, description="fit every q-th sample after an anti-aliasing low-pass "
                          "(1 = the whole band); the fit sees the band below 0.4 / (q dt)")
    window: list[float] | None = Field(None, description="fit only [start_s, stop_s) of the record [s], "
                                               "t counted from its first sample")
    max_memory_GiB: float = Field(4.0, gt=0, description="refuse (in one line, naming the decimation that would "
                                  "fit) a fit whose estimated peak memory exceeds this [GiB]")

    @field_validator("window")
    @classmethod
    def _ordered(cls, value):
        if value is not None and len(value) != 2:
            raise ValueError(f"{value} must be two times [start_s, stop_s]")
        if value is not None and not 0 <= value[0] < value[1]:
            raise ValueError(f"[{value[0]:g}, {value[1]:g}] must satisfy 0 <= start_s < stop_s")
        return value


class OutputConfig(_Strict):
    """``output``: where and what to write."""

    directory: str = Field("runs", description="parent of timestamped run folders (relative to the CWD)")
    plots: bool = Field(True, description="write the run's figures")
    figures: Literal["svg", "png"] = Field("svg", description="figure format: svg (drawn in the run's process, "
                                           "no matplotlib) or png (matplotlib)")


class RunConfig(_Strict):
    """One identification run."""

    title: str | None = None
    sample: SampleConfig
    model: ModelConfig = Field(default_factory=ModelConfig)
    excitation: PluginRef | None = Field(
        None, description="designed input; optional when the backend reads the recorded input (file backend)"
    )
    backend: PluginRef
    compensator: CompensatorRef = Field(default_factory=CompensatorRef)
    solver: SolverRef = Field(default_factory=SolverRef)
    nuisance: NuisanceConfig = Field(default_factory=NuisanceConfig)
    identifiability: IdentifiabilityConfig = Field(default_factory=IdentifiabilityConfig)
    uncertainty: UncertaintyConfig = Field(default_factory=UncertaintyConfig)
    estimation: EstimationConfig = Field(default_factory=EstimationConfig)
    calibration: dict[str, Any] | None = Field(
        None, description="makes the run a transducer calibration (see mbus_framework.studies.transducer_calibration)"
    )
    design: dict[str, Any] | None = Field(
        None, description="options of --design-excitation (see mbus_framework.studies.design)"
    )
    output: OutputConfig = Field(default_factory=OutputConfig)


def read_yaml(path: str | Path) -> dict[str, Any]:
    """Safe-load a YAML mapping from ``path`` (bounded: see :mod:`~mbus_framework.pipeline.yaml_loader`);
    the caller's own copy (the file is read every time; the same text is parsed once)."""
    text = read_config_text(path)
    try:
        data = _parsed_yaml(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: {describe_yaml_error(exc)}") from None
    if data is None:
        raise ConfigError(f"{path}: config file is empty")
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: top level must be a mapping of sections, not {type(data).__name__}")
    return copy.deepcopy(data)


@functools.lru_cache(maxsize=16)
def _parsed_yaml(text: str) -> Any:
    """:func:`yaml_load` remembered by text: ``mbus-run`` reads its config up to five times
    (which kind of config, then the validation), and PyYAML's pure-Python parser costs about 5 ms
    a time. Callers get a deep copy (:func:`read_yaml`), never this object."""
    return yaml_load(text)


def config_mapping_or_none(path: str | Path) -> dict[str, Any] | None:
    """The YAML mapping of a ``.yaml``/``.yml`` file, or None when it is not a readable config
    (used to recognise special config kinds before the full validation)."""
    p = Path(path)
    if p.suffix.lower() not in (".yaml", ".yml") or not p.is_file():
        return None
    try:
        return read_yaml(p)
    except ConfigError:
        return None


def apply_overrides(data: dict[str, Any], overrides: list[str], where: str = "--set") -> dict[str, Any]:
    """Apply ``dotted.key=value`` overrides (value parsed as YAML) to a copy of ``data``."""
    out = copy.deepcopy(data)
    for item in overrides:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key or any(not part for part in key.split(".")):
            raise ConfigError(f"{where} {shown(item)}: expected dotted.key=value")
        try:
            value = yaml_load(text) if text.strip() else ""
        except LimitError as exc:
            raise ConfigError(f"{where} {shown(key)}: {describe_yaml_error(exc)}") from None
        except yaml.YAMLError:
            value = text
        node = out
        parts = key.split(".")
        for i, part in enumerate(parts[:-1]):
            child = node.get(part)
            if child is None:
                child = node[part] = {}
            if not isinstance(child, dict):
                raise ConfigError(f"{where} {shown(item)}: {shown('.'.join(parts[: i + 1]))} is not a section")
            node = child
        node[parts[-1]] = value
    return out


def load_config(path: str | Path, overrides: list[str] | None = None, check_files: bool = False) -> RunConfig:
    """Read, override and validate (stage 1) a run config; file paths become absolute
    (:mod:`~mbus_framework.pipeline.config_paths`: the file's relative to its folder, ``--set``
    ones relative to the working directory) and with ``check_files`` the input files must exist."""
    from mbus_framework.pipeline.config_paths import resolve

    written = read_yaml(path)
    data = resolve(written, apply_overrides(written, overrides or []), Path(path), str(path), check_files)
    return validate_structure(data, str(path))


def validate_structure(data: dict[str, Any], source: str = "<config>") -> RunConfig:
    reject_non_finite(data, source)
    try:
        return RunConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{source}: {format_validation_error(exc, RunConfig)}") from None


def reject_non_finite(data: Any, source: str | None = None, where: str = "") -> None:
    """ConfigError naming the key path of the first NaN or infinite number in ``data``."""
    if isinstance(data, float) and not math.isfinite(data):
        prefix = f"{source}: " if source else ""
        raise ConfigError(f"{prefix}{where or '(value)'}: must be a finite number (got {data})")
    if isinstance(data, dict):
        for key, value in data.items():
            reject_non_finite(value, source, f"{where}.{_key(key)}" if where else _key(key))
    elif isinstance(data, (list, tuple)):
        for i, value in enumerate(data):
            reject_non_finite(value, source, f"{where}[{i}]")


def validate_options(options_model: type[BaseModel], options: Any, where: str, source: str | None = None):
    """Stage 2: validate a plugin's ``options`` mapping; errors name ``where`` (a key path)."""
    if options is None:
        options = {}
    if not isinstance(options, dict):
        prefix = f"{source}: " if source else ""
        raise ConfigError(f"{prefix}{where}: must be a mapping, not {type(options).__name__}")
    reject_non_finite(options, source, where)
    try:
        validated = options_model.model_validate(options)
    except ValidationError as exc:
        prefix = f"{source}: " if source else ""
        raise ConfigError(f"{prefix}{format_validation_error(exc, options_model, where)}") from None
    reject_non_finite(validated.model_dump(), source, where)  # 'nan' and 'inf' given as strings
    return validated


def _key(key: Any) -> str:
    return key if isinstance(key, str) and len(key) <= 60 and key.isprintable() else shown(key)


def format_validation_error(exc: ValidationError, root: type[BaseModel], prefix: str = "") -> str:
    """One line for the first error: key path, problem, offending value, suggestion."""
    # A misspelt key shows up twice (unknown key + missing key); the unknown key explains both.
    errors = sorted(exc.errors(), key=lambda e: e["type"] != "extra_forbidden")
    err = errors[0]
    loc = [_key(p) if isinstance(p, str) else str(p) for p in err["loc"]]
    path = ".".join([prefix] * bool(prefix) + loc)
    more = f" (and {len(errors) - 1} more problem{'s' * (len(errors) > 2)})" if len(errors) > 1 else ""
    kind = err["type"]
    if kind == "extra_forbidden":
        choices = _field_names(root, err["loc"][:-1])
        if not choices:  # e.g. options for a plugin that has none (compensator 'none')
            parent = path.rsplit(".", 1)[0] if "." in path else "this section"
            why = " (the chosen plugin has no options)" if parent.endswith("options") else ""
            return f"{path}: unknown key; {parent} takes no keys{why}{more}"
        hint = did_you_mean(loc[-1], choices) if len(loc[-1]) <= 60 else ""
        return f"{path}: unknown key{hint}; allowed: {', '.join(choices)}{more}"
    if kind == "missing":
        return f"{path}: required key is missing{more}"
    got = err.get("input")
    value = "" if isinstance(got, (dict, list)) else f" (got {shown(got)})"
    msg = err["msg"]
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    return f"{path}: {msg}{value}{more}"


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
