"""Everything a plugin author imports, in one module (as ``conda.plugins`` does).

A plugin module implements one or more hooks, each returning a list of spec records::

    from mbus_framework.plugins import ChainModel, KelvinVoigtLaw, MediumModelSpec, hookimpl

    @hookimpl
    def mbus_medium_models():
        return [MediumModelSpec("my_chain", MyChain, "one-line summary")]

and is found through an entry point in the group ``mbus_framework``::

    [project.entry-points.mbus_framework]
    my_models = "my_package.models"

The names below are the stable plugin API; where they live inside the core (``interfaces/``,
``engine/``, ``estimation/``) is not. Reusable contract test suites are in
:mod:`mbus_framework.testing`. Importing this module does not load the run pipeline.
"""
from __future__ import annotations

from mbus_framework.engine.arrays import array_dtype, to_casadi, zeros_like_params
from mbus_framework.engine.chain import (
    ChainModel,
    ChainOptions,
    GeneralizedMaxwellLaw,
    KelvinVoigtLaw,
    LinkLaw,
    LinkMatrices,
    LinkParameter,
    MaxwellLaw,
    StandardLinearSolidLaw,
    damping,
    stiffness,
)
from mbus_framework.errors import (
    ConfigError,
    DataError,
    EstimationError,
    InstrumentError,
    MbusError,
    PluginError,
)
from mbus_framework.estimation.problem import FitProblem, FitResult, Progress, Solver
from mbus_framework.interfaces.backend import AcquisitionContext, Backend, Measurement
from mbus_framework.interfaces.compensator import Compensator
from mbus_framework.interfaces.excitation import DesignedExcitation, Excitation, ExcitationOptions, Waveform
from mbus_framework.interfaces.hookspecs import (
    BackendSpec,
    CompensatorSpec,
    ExcitationSpec,
    MediumModelSpec,
    SolverSpec,
    hookimpl,
)
from mbus_framework.interfaces.model import MediumModel, NoOptions, Parameter, Property, StateSpace
from mbus_framework.interfaces.plugin_manager import new_plugin_manager
from mbus_framework.interfaces.registry import Registry, default_registry
from mbus_framework.interfaces.sample import Sample

__all__ = [
    # the hook marker and the spec records the hooks return
    "hookimpl", "MediumModelSpec", "ExcitationSpec", "SolverSpec", "CompensatorSpec", "BackendSpec",
    # medium models
    "MediumModel", "Parameter", "Property", "StateSpace", "NoOptions", "Sample",
    "ChainModel", "ChainOptions", "LinkLaw", "LinkMatrices", "LinkParameter", "stiffness", "damping",
    "KelvinVoigtLaw", "MaxwellLaw", "StandardLinearSolidLaw", "GeneralizedMaxwellLaw",
    "array_dtype", "zeros_like_params", "to_casadi",
    # excitations, solvers, compensators, backends
    "Excitation", "ExcitationOptions", "DesignedExcitation", "Waveform",
    "Solver", "FitProblem", "FitResult", "Progress",
    "Compensator",
    "Backend", "AcquisitionContext", "Measurement",
    # plugin discovery (for tests of a plugin package)
    "new_plugin_manager", "Registry", "default_registry",
    # one-line user errors
    "MbusError", "ConfigError", "DataError", "EstimationError", "InstrumentError", "PluginError",
]
