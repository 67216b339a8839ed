"""Hook specifications of mbus: how plugins register implementations.

The marker name, the plugin-manager project name and the entry-point group are all
``mbus_framework``. A plugin module (or object) implements one or more of the hooks below,
each returning a list of spec records; the behaviour lives in the registered classes, whose
interfaces are in :mod:`mbus_framework.interfaces.model`, :mod:`~mbus_framework.interfaces.excitation`,
:mod:`~mbus_framework.estimation.problem`, :mod:`~mbus_framework.interfaces.compensator` and
:mod:`~mbus_framework.interfaces.backend`.

A third-party package exposes its module through an entry point::

    [project.entry-points.mbus_framework]
    my_models = "my_package.models"

and the module defines, for example::

    from mbus_framework.interfaces.hookspecs import MediumModelSpec, hookimpl

    @hookimpl
    def mbus_medium_models():
        return [MediumModelSpec("my_chain", MyChain, "one-line summary")]
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import pluggy

PROJECT = "mbus_framework"
hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)



@dataclass(frozen=True)
class PluginSpec:
    """A registered implementation: its config name, its class and a one-line summary."""

    name: str
    implementation: type
    summary: str = ""
    kind: ClassVar[str] = ""


@dataclass(frozen=True)
class MediumModelSpec(PluginSpec):
    implementation: type  # a subclass of mbus_framework.plugins.MediumModel
    kind: ClassVar[str] = "model"


@dataclass(frozen=True)
class ExcitationSpec(PluginSpec):
    implementation: type  # a subclass of mbus_framework.plugins.Excitation
    kind: ClassVar[str] = "excitation"


@dataclass(frozen=True)
class SolverSpec(PluginSpec):
    implementation: type  # a subclass of mbus_framework.plugins.Solver
    kind: ClassVar[str] = "solver"


@dataclass(frozen=True)
class CompensatorSpec(PluginSpec):
    implementation: type  # a subclass of mbus_framework.plugins.Compensator
    kind: ClassVar[str] = "compensator"


@dataclass(frozen=True)
class BackendSpec(PluginSpec):
    implementation: type  # a subclass of mbus_framework.plugins.Backend
    kind: ClassVar[str] = "backend"


class MbusHookSpecs:
    """The five registration hooks. Each returns a list of spec records."""

    @hookspec
    def mbus_medium_models(self) -> list[MediumModelSpec]:
        """Medium models (lumped viscoelastic samples as state-space models)."""

    @hookspec
    def mbus_excitations(self) -> list[ExcitationSpec]:
        """Excitation signals (PRBS, sweeps, ...)."""

    @hookspec
    def mbus_solvers(self) -> list[SolverSpec]:
        """Parameter estimators."""

    @hookspec
    def mbus_compensators(self) -> list[CompensatorSpec]:
        """Transducer compensators applied between acquisition and estimation."""

    @hookspec
    def mbus_backends(self) -> list[BackendSpec]:
        """Instrument backends that deliver a measured input/output record."""


HOOKS_BY_KIND = {
    "model": "mbus_medium_models",
    "excitation": "mbus_excitations",
    "solver": "mbus_solvers",
    "compensator": "mbus_compensators",
    "backend": "mbus_backends",
}
SPEC_BY_KIND = {
    "model": MediumModelSpec,
    "excitation": ExcitationSpec,
    "solver": SolverSpec,
    "compensator": CompensatorSpec,
    "backend": BackendSpec,
}
