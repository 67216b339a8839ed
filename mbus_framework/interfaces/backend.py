"""Instrument-backend interface: something that delivers a measured input/output record."""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np
from pydantic import BaseModel

from mbus_framework.errors import DataError
from mbus_framework.interfaces.model import NoOptions

if TYPE_CHECKING:  # pragma: no cover
    from mbus_framework.interfaces.excitation import Waveform
    from mbus_framework.interfaces.model import MediumModel
    from mbus_framework.interfaces.sample import Sample


MIN_SAMPLES = 16
STEP_TOLERANCE = 1e-6


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


def check_record(path: Any, t, u, y) -> Measurement:
    """A :class:`Measurement` from arrays t [s], u, y after the checks every fit needs: equal
    lengths, at least :data:`MIN_SAMPLES` samples, finite values, a uniform increasing time step
    (relative jitter below :data:`STEP_TOLERANCE`); t is shifted to start at 0. Problems raise
    a one-line DataError starting with ``path`` (a file name, or e.g. ``<arrays>``)."""
    t, u, y = (np.asarray(a, dtype=float).ravel() for a in (t, u, y))
    if not (len(t) == len(u) == len(y)):
        raise DataError(f"{path}: length mismatch (t {len(t)}, u {len(u)}, y {len(y)} samples)")
    if len(t) < MIN_SAMPLES:
        raise DataError(f"{path}: only {len(t)} samples; need at least {MIN_SAMPLES}")
    for name, a in (("t", t), ("u", u), ("y", y)):
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise DataError(f"{path}: column {name} has {bad.size} non-finite or non-numeric value(s) (first at row {bad[0] + 1})")
    steps = np.diff(t)
    dt = float(np.median(steps))
    if dt <= 0:
        raise DataError(f"{path}: time column t is not increasing")
    worst = int(np.argmax(np.abs(steps - dt)))
    if abs(steps[worst] - dt) > STEP_TOLERANCE * dt:
        raise DataError(
            f"{path}: non-uniform time step (step {steps[worst]:.6g} s at row {worst + 2}, median {dt:.6g} s)"
        )
    return Measurement(t - t[0], u, y, meta={"source": str(path)})


class PluginLookup(Protocol):
    """What a backend may use of the plugin registry (``mbus_framework.plugins.Registry``)."""

    def get(self, kind: str, name: str) -> Any: ...


@dataclass
class AcquisitionContext:
    """What a backend may need: the designed excitation (None when the config has none: a
    backend with ``needs_excitation = False`` then takes the input from the record), the
    sample, the fitted model and the plugin registry (to build a different 'true' medium),
    and the run directory where shots must be saved as they arrive."""

    excitation: "Waveform | None"
    sample: "Sample"
    model: "MediumModel"
    registry: PluginLookup
    run_dir: Path | None = None
    config_path: str = "<config>"


class Backend(ABC):
    """Base class of instrument backends; ``options`` is an instance of ``Options``."""

    Options: ClassVar[type[BaseModel]] = NoOptions
    summary: ClassVar[str] = ""
    #: True when the backend plays (or simulates) the designed excitation, so a config must
    #: have an ``excitation`` section; False when it reads the input from a record.
    needs_excitation: ClassVar[bool] = True

    def __init__(self, options: BaseModel):
        self.options = options

    @abstractmethod
    def acquire(self, context: AcquisitionContext) -> Measurement:
        """Play the excitation (if the backend can) and return the measured record."""
