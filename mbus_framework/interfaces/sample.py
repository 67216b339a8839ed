"""Sample geometry: the pressure-wave column between the two transducers."""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Sample:
    """Cylindrical pressure-wave column (dissertation Section 3.2.1).

    length:   L, sample thickness between the transducer faces [m]
    diameter: D, diameter of the transducer element [m]
    density:  rho [kg/m^3]
    """

    length: float
    diameter: float
    density: float

    @property
    def area(self) -> float:
        """Cross-section A = pi D^2 / 4 [m^2]."""
        return math.pi * self.diameter**2 / 4.0

    @property
    def circumference(self) -> float:
        """Lateral perimeter pi D [m], the shear surface per unit length."""
        return math.pi * self.diameter

    @property
    def mass(self) -> float:
        """Mass of the whole column rho A L [kg]."""
        return self.density * self.area * self.length
