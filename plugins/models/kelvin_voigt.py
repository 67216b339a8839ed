"""Kelvin-Voigt chain (dissertation eqs. 3.1-3.21 and 3.32-3.38).

The column (length L, diameter D, density rho) is cut into n elements of mass
m = rho (pi D^2 / 4) L / n [kg]. Masses 1..n carry displacements x_i; the end masses are
m/2 (eq. 3.13; for n = 1 the single mass is m/2). Neighbours are joined by a normal spring
k_sigma [N/m] parallel to a dashpot b_sigma [N s/m]; each mass is tied to the stationary
surroundings by a shear spring k_tau [N/m] and dashpot b_tau [N s/m]; the last mass is tied
to the receiver (a fixed wall) by one more normal link. The force u acts on mass 1:

    M x'' + B x' + K x = e_1 u,     y = k_sigma x_n + b_sigma x_n'

K = k_sigma T + k_tau I, B = b_sigma T + b_tau I, T = tridiag(-1, 2, -1) with T[0,0] = 1
(eq. 3.18), z = [x, x'] (eq. 3.10). Material properties (eqs. 3.32, 3.36-3.38):

    E_sigma = (L/n) / (pi D^2/4) k_sigma [Pa],   eta_sigma = (L/n) / (pi D^2/4) b_sigma [Pa s]
    E_tau   = k_tau / (pi D) [Pa],               eta_tau   = b_tau / (pi D) [Pa s]

Eq. 3.28 writes rho with the whole column volume; the per-element reading m = rho A L/n is
the one consistent with eqs. 3.32-3.36 and is used here.
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.engine.chain import ChainModel, KelvinVoigtLaw
from mbus_framework.interfaces.hookspecs import MediumModelSpec, hookimpl
from mbus_plugins.models.bounds import Elements
from mbus_framework.engine.physics import first_arrival_time


class KelvinVoigtOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    n_elements: Elements = Field(10, description="number of elements n")


class KelvinVoigtChain(ChainModel):
    """Chain of n masses joined by Kelvin-Voigt links, with Kelvin-Voigt shear to ground.

    Assembled by :func:`mbus_framework.engine.chain.assemble_chain` from :class:`KelvinVoigtLaw` in
    both directions; parameters [k_sigma, b_sigma, k_tau, b_tau], properties
    [E_sigma, eta_sigma, E_tau, eta_tau]. Numerically identical to eqs. 3.3-3.21 (tested).
    """

    Options = KelvinVoigtOptions
    summary = "Kelvin-Voigt chain, eqs. 3.1-3.21 (k_sigma, b_sigma, k_tau, b_tau)"
    normal = KelvinVoigtLaw()
    shear = KelvinVoigtLaw()

    @property
    def parameters(self):
        names = {
            "k_sigma": "normal stiffness between masses",
            "b_sigma": "normal damping between masses",
            "k_tau": "shear stiffness to the surroundings",
            "b_tau": "shear damping to the surroundings",
        }
        return tuple(
            type(p)(p.name, p.unit, names[p.name], p.lower, p.upper, p.typical, p.time_exponent)
            for p in super().parameters
        )

    # -- physics-based initial values (Section 3.5.1) -------------------------------------
    def initial_guess(self, t, u, y) -> np.ndarray:
        """Sound speed from the first arrival gives k_sigma; the rest from typical ratios.

        v = L / t_arrival, E_sigma = rho v^2, k_sigma = E_sigma A / (L/n), k_tau = k_sigma/10;
        the dampings keep their typical values (eta ~ 1 kPa s). The chain's low-frequency
        wave speed is (L/n) sqrt(k_sigma / m), the same relation.
        """
        theta = np.array([p.typical for p in self.parameters], dtype=float)
        t_arr = first_arrival_time(t, u, y)
        if t_arr is not None and t_arr > 0:
            speed = self.sample.length / t_arr
            theta[0] = self.sample.density * speed**2 / self.geometry_factor("sigma")
            theta[2] = theta[0] / 10.0
        return theta


@hookimpl
def mbus_medium_models():
    return [MediumModelSpec("kelvin_voigt", KelvinVoigtChain, KelvinVoigtChain.summary)]
