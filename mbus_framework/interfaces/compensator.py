"""Compensator interface: remove (or model) the transducers' own dynamics."""
from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

from pydantic import BaseModel

from mbus_framework.interfaces.backend import Measurement
from mbus_framework.interfaces.model import NoOptions


class Compensator(ABC):
    """Base class of compensators; ``options`` is an instance of ``Options``.

    ``apply`` returns the record the estimator should fit. A compensator that instead puts
    the transducer response into the model's output path returns the record unchanged and
    overrides :meth:`output_filter`.
    """

    Options: ClassVar[type[BaseModel]] = NoOptions
    summary: ClassVar[str] = ""

    def __init__(self, options: BaseModel):
        self.options = options

    @abstractmethod
    def apply(self, measurement: Measurement) -> Measurement:
        """The compensated record."""

    def output_filter(self):
        """Optional linear filter applied to model outputs (and sensitivities): a callable
        ``f(x, dt) -> x`` acting along axis 0, or None."""
        return None

    def noise_filter(self):
        """The linear map F the compensation applied to the record, hence to its noise, or None.

        An object with ``__call__(x, dt)`` and ``adjoint(x, dt)`` (the transpose) along axis 0.
        The run then reports sandwich standard errors for noise sigma F e (e white), instead
        of the white-noise formula that would be too small."""
        return None
