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

from typing import Mapping

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.arrays import zeros_like_params
from mbus_framework.hookspecs import MediumModelSpec, hookimpl
from mbus_framework.model import MediumModel, Parameter, Property, StateSpace
from mbus_framework.physics import first_arrival_time


class KelvinVoigtOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    n_elements: int = Field(10, ge=1, le=400, description="number of elements n")


class KelvinVoigtChain(MediumModel):
    """Chain of n masses joined by Kelvin-Voigt links, with Kelvin-Voigt shear to ground."""

    Options = KelvinVoigtOptions
    summary = "Kelvin-Voigt chain, eqs. 3.1-3.21 (k_sigma, b_sigma, k_tau, b_tau)"

    @property
    def n(self) -> int:
        return int(self.options.n_elements)

    @property
    def element_length(self) -> float:
        return self.sample.length / self.n

    @property
    def element_mass(self) -> float:
        """m = rho (pi D^2/4) L / n [kg]."""
        return self.sample.mass / self.n

    @property
    def parameters(self):
        k_typ = 2.0e9 * self.sample.area / self.element_length  # E ~ 2 GPa
        b_typ = 1.0e3 * self.sample.area / self.element_length  # eta ~ 1 kPa s
        return (
            Parameter("k_sigma", "N/m", "normal stiffness between masses", 0.0, np.inf, k_typ, 2.0),
            Parameter("b_sigma", "N s/m", "normal damping between masses", 0.0, np.inf, b_typ, 1.0),
            Parameter("k_tau", "N/m", "shear stiffness to the surroundings", 0.0, np.inf, k_typ / 10, 2.0),
            Parameter("b_tau", "N s/m", "shear damping to the surroundings", 0.0, np.inf, b_typ, 1.0),
        )

    @property
    def properties(self):
        return (
            Property("E_sigma", "Pa", "normal elastic modulus"),
            Property("eta_sigma", "Pa s", "normal viscosity"),
            Property("E_tau", "Pa", "shear elastic modulus"),
            Property("eta_tau", "Pa s", "shear viscosity"),
        )

    def masses(self) -> np.ndarray:
        m = np.full(self.n, self.element_mass)
        m[0] = m[-1] = self.element_mass / 2.0
        return m

    def state_space(self, theta) -> StateSpace:
        k_s, b_s, k_t, b_t = theta[0], theta[1], theta[2], theta[3]
        n = self.n
        inv_m = 1.0 / self.masses()
        A = zeros_like_params((2 * n, 2 * n), theta)
        for i in range(n):
            A[i, n + i] = 1.0
            links = 1 if i == 0 else 2  # normal links attached to mass i (eq. 3.18)
            A[n + i, i] = -(links * k_s + k_t) * inv_m[i]
            A[n + i, n + i] = -(links * b_s + b_t) * inv_m[i]
            if i > 0:
                A[n + i, i - 1] = k_s * inv_m[i]
                A[n + i, n + i - 1] = b_s * inv_m[i]
            if i < n - 1:
                A[n + i, i + 1] = k_s * inv_m[i]
                A[n + i, n + i + 1] = b_s * inv_m[i]
        B = zeros_like_params((2 * n, 1), theta)
        B[n, 0] = inv_m[0]
        C = zeros_like_params((1, 2 * n), theta)
        C[0, n - 1] = k_s
        C[0, 2 * n - 1] = b_s
        D = zeros_like_params((1, 1), theta)
        return StateSpace(A, B, C, D)

    # -- properties (eqs. 3.32-3.38) ------------------------------------------------------
    def _normal_factor(self) -> float:
        return self.element_length / self.sample.area

    def to_properties(self, theta) -> dict[str, float]:
        k_s, b_s, k_t, b_t = (float(v) for v in theta)
        f, c = self._normal_factor(), self.sample.circumference
        return {"E_sigma": f * k_s, "eta_sigma": f * b_s, "E_tau": k_t / c, "eta_tau": b_t / c}

    def from_properties(self, properties: Mapping[str, float]) -> np.ndarray:
        f, c = self._normal_factor(), self.sample.circumference
        return np.array(
            [
                properties["E_sigma"] / f,
                properties["eta_sigma"] / f,
                properties["E_tau"] * c,
                properties["eta_tau"] * c,
            ]
        )

    # -- physics-based initial values (Section 3.5.1) -------------------------------------
    def initial_guess(self, t, u, y) -> np.ndarray:
        """Sound speed from the first arrival gives k_sigma; the rest from typical ratios.

        v = L / t_arrival, E_sigma = rho v^2, k_sigma = E_sigma A / (L/n). The chain's low-
        frequency wave speed is (L/n) sqrt(k_sigma / m), the same relation.
        """
        theta = np.array([p.typical for p in self.parameters], dtype=float)
        t_arr = first_arrival_time(t, u, y)
        if t_arr is not None and t_arr > 0:
            speed = self.sample.length / t_arr
            theta[0] = self.sample.density * speed**2 / self._normal_factor()
            theta[2] = theta[0] / 10.0
        return theta


@hookimpl
def mbus_medium_models():
    return [MediumModelSpec("kelvin_voigt", KelvinVoigtChain, KelvinVoigtChain.summary)]
