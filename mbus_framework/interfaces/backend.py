"""Instrument-backend interface: something that delivers a measured input/output record."""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np
from pydantic import BaseModel

from mbus_framework.interfaces.model import NoOptions

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.interfaces.excitation import Waveform
    from mbus_framework.interfaces.model import MediumModel
    from mbus_framework.interfaces.sample import Sample


@dataclass
class Measurement:
    """A measured record: t [s] uniform, u the input (force or volts), y the output.

    ``truth`` holds the true model parameters when the rig is simulated; ``meta`` holds
    everything a reader needs to trust the record (instrument identities, settings, noise).
    """

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    truth: dict[str, float] | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])


class PluginLookup(Protocol):
    """What a backend may use of the plugin registry (``mbus_framework.registry.Registry``)."""

    def get(self, kind: str, name: str) -> Any: ...


@dataclass
class AcquisitionContext:
    """What a backend may need: the designed excitation, the sample, the fitted model and
    the plugin registry (to build a different 'true' medium), and the run directory where
    shots must be saved as they arrive."""

    excitation: "Waveform"
    sample: "Sample"
    model: "MediumModel"
    registry: PluginLookup
    run_dir: Path | None = None
    config_path: str = "<config>"


class Backend(ABC):
    """Base class of instrument backends; ``options`` is an instance of ``Options``."""

    Options: ClassVar[type[BaseModel]] = NoOptions
    summary: ClassVar[str] = ""

    def __init__(self, options: BaseModel):
        self.options = options

    @abstractmethod
    def acquire(self, context: AcquisitionContext) -> Measurement:
        """Play the excitation (if the backend can) and return the measured record."""
