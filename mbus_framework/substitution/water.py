"""Pure water at atmospheric pressure: speed of sound and density from temperature.

c0(T) [m/s], Marczak (1997), 0-95 deg C, T in deg C:
    c0 = 1.402385e3 + 5.038813 T - 5.799136e-2 T^2 + 3.287156e-4 T^3 - 1.398845e-6 T^4 + 2.787860e-9 T^5
rho0(T) [kg/m^3], Kell (1975), 0-150 deg C:
    rho0 = (999.83952 + 16.945176 T - 7.9870401e-3 T^2 - 46.170461e-6 T^3 + 105.56302e-9 T^4
            - 280.54253e-12 T^5) / (1 + 16.879850e-3 T)
"""
from __future__ import annotations

from dataclasses import dataclass

_MARCZAK = (1.402385e3, 5.038813, -5.799136e-2, 3.287156e-4, -1.398845e-6, 2.787860e-9)
_KELL = (999.83952, 16.945176, -7.9870401e-3, -46.170461e-6, 105.56302e-9, -280.54253e-12)


def _poly(coefficients, x: float) -> float:
    return sum(c * x**i for i, c in enumerate(coefficients))


def sound_speed(temperature_C: float) -> float:
    """Speed of sound in pure water [m/s] (Marczak 1997)."""
    _check(temperature_C)
    return _poly(_MARCZAK, temperature_C)


def density(temperature_C: float) -> float:
    """Density of pure water [kg/m^3] (Kell 1975)."""
    _check(temperature_C)
    return _poly(_KELL, temperature_C) / (1 + 16.879850e-3 * temperature_C)


def _check(temperature_C: float) -> None:
    if not 0.0 <= float(temperature_C) <= 95.0:
        raise ValueError(f"water temperature {temperature_C} deg C is outside 0-95 deg C")


@dataclass(frozen=True)
class Water:
    """The coupling fluid: speed c [m/s] and density rho [kg/m^3]; impedance Z = rho c [Rayl]."""

    temperature_C: float
    speed: float
    density: float

    @classmethod
    def at(cls, temperature_C: float) -> "Water":
        return cls(float(temperature_C), sound_speed(temperature_C), density(temperature_C))

    @property
    def impedance(self) -> float:
        return self.density * self.speed
