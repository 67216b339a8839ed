"""The configured plugin instances of one run, built from a validated RunConfig."""
from __future__ import annotations

from dataclasses import dataclass

from mbus_framework.errors import ConfigError
from mbus_framework.estimation.problem import Solver
from mbus_framework.interfaces.backend import Backend
from mbus_framework.interfaces.compensator import Compensator
from mbus_framework.interfaces.excitation import Excitation
from mbus_framework.interfaces.model import MediumModel
from mbus_framework.interfaces.registry import Registry, default_registry
from mbus_framework.interfaces.sample import Sample
from mbus_framework.pipeline.config import RunConfig, validate_options
from mbus_framework.pipeline.fixed_names import resolve_fixed


@dataclass
class Components:
    """The configured plugin instances of one run."""

    config: RunConfig
    source: str
    registry: Registry
    sample: Sample
    model: MediumModel
    excitation: Excitation | None  # None: the backend reads the input from the record
    backend: Backend
    compensator: Compensator
    solver: Solver


def build_components(config: RunConfig, source: str = "<config>", registry: Registry | None = None) -> Components:
    """Stage-2 validation: look up every plugin and validate its options."""
    registry = registry or default_registry()

    def make(kind: str, ref, section: str, *args):
        spec = registry.get(kind, ref.name)
        options = validate_options(spec.implementation.Options, ref.options, f"{section}.options", source)
        return spec.implementation(*args, options)

    def named(kind: str, ref, section: str, *args):
        try:
            return make(kind, ref, section, *args)
        except ConfigError:
            raise
        except Exception as exc:
            from mbus_framework.errors import MbusError

            if isinstance(exc, MbusError):
                raise type(exc)(f"{source}: {section}.name: {exc}") from None
            raise

    sample = Sample(config.sample.length, config.sample.diameter, config.sample.density)
    model = named("model", config.model, "model", sample)
    fixed = resolve_fixed(model, config.model.fixed, "model.fixed", source)
    if fixed != dict(config.model.fixed):  # property names given: every consumer sees parameters
        config = config.model_copy(update={"model": config.model.model_copy(update={"fixed": fixed})})
    backend = named("backend", config.backend, "backend")
    if config.excitation is None and backend.needs_excitation:
        raise ConfigError(
            f"{source}: excitation: required by backend '{config.backend.name}' (it plays the excitation); "
            f"only a backend that reads the recorded input (file) can do without"
        )
    return Components(
        config=config,
        source=source,
        registry=registry,
        sample=sample,
        model=model,
        excitation=named("excitation", config.excitation, "excitation") if config.excitation else None,
        backend=backend,
        compensator=named("compensator", config.compensator, "compensator"),
        solver=named("solver", config.solver, "solver"),
    )


def require_excitation(c: Components, what: str) -> Excitation:
    """The configured excitation, or a ConfigError saying that ``what`` needs one."""
    if c.excitation is None:
        raise ConfigError(f"{c.source}: excitation: {what} needs an excitation section (the designed input)")
    return c.excitation
