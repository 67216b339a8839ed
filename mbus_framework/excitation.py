"""Excitation interface: a designed input waveform and its spectrum."""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel

from .model import NoOptions


@dataclass(frozen=True)
class Waveform:
    """A sampled excitation: times t [s] (uniform, from 0) and values u (amplitude units)."""

    t: np.ndarray
    u: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    @property
    def sample_rate(self) -> float:
        return 1.0 / self.dt


@dataclass(frozen=True)
class Spectrum:
    """One-sided power spectrum: frequencies f [Hz], power density (arbitrary units)."""

    f: np.ndarray
    power: np.ndarray

    def bandwidth_3db(self) -> float:
        """Frequency [Hz] above which the power stays below half its low-frequency peak.

        For a PRBS of bit width T_b the envelope is sinc^2(f T_b), so this is about
        0.443 / T_b (Fig. 3.7).
        """
        p = self.power
        peak = p.max()
        below = np.nonzero(p >= peak / 2.0)[0]
        return float(self.f[below[-1]]) if below.size else 0.0


def power_spectrum(u: np.ndarray, dt: float) -> Spectrum:
    """Periodogram of ``u`` (mean removed), frequencies up to Nyquist."""
    u = np.asarray(u, dtype=float) - np.mean(u)
    U = np.fft.rfft(u)
    f = np.fft.rfftfreq(len(u), dt)
    return Spectrum(f, (np.abs(U) ** 2) * dt / len(u))


class Excitation(ABC):
    """Base class of excitation plugins; ``options`` is an instance of ``Options``."""

    Options: ClassVar[type[BaseModel]] = NoOptions
    summary: ClassVar[str] = ""

    def __init__(self, options: BaseModel):
        self.options = options

    @abstractmethod
    def waveform(self) -> Waveform:
        """The designed excitation samples."""

    def spectrum(self) -> Spectrum:
        w = self.waveform()
        return power_spectrum(w.u, w.dt)
