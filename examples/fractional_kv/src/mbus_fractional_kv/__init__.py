"""Fractional Kelvin-Voigt chain for mbus: an example model plugin (a complete package).

Link law (normal direction): a spring k [N/m] parallel to a springpot c [N s^alpha/m],

    F = k delta + c D^alpha delta,        Z(s) = F/delta = k + c s^alpha,   0 < alpha < 1,

(D^alpha the Caputo derivative; alpha = 1 is a dashpot, alpha = 0 a spring). The springpot
is approximated by a Prony series of M Maxwell arms around its crossover frequency
w_c = (k/c)^(1/alpha), where the elastic and fractional parts are equal:

    c s^alpha ~= sum_j k_j s tau_j / (1 + s tau_j),   tau_j = r_j / w_c,   k_j = k w_j,

r_j log-spaced over +-(decades + 1) decades, weights w_j >= 0 fitted once (non-negative
least squares) to (j x)^alpha on |x| in [10^-decades, 10^decades] (about 0.1 % error at
alpha = 0.5). The arms are generalized-Maxwell arms with spring elongations as states, so
the chain is passive and exactly time-scalable. Shear links are Kelvin-Voigt (k_tau, b_tau).

Parameters: k_sigma [N/m] (time exponent 2), c_sigma [N s^alpha/m] (2 - alpha),
k_tau [N/m] (2), b_tau [N s/m] (1). Properties (eqs. 3.32-3.38): E_sigma = g k_sigma [Pa],
eta_alpha_sigma = g c_sigma [Pa s^alpha] with g = (L/n)/(pi D^2/4); E_tau = k_tau/(pi D),
eta_tau = b_tau/(pi D).
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.optimize import nnls

from mbus_framework.plugins import (
    ChainModel,
    KelvinVoigtLaw,
    LinkLaw,
    LinkMatrices,
    LinkParameter,
    MediumModelSpec,
    hookimpl,
    stiffness,
)


class FractionalKelvinVoigtLaw(LinkLaw):
    """Spring k parallel to a springpot c (order alpha), springpot as a Prony series."""

    name = "fractional_kelvin_voigt"
    summary = "spring parallel to a springpot (Prony-series approximation)"

    def __init__(self, alpha: float = 0.5, decades: int = 2, arms_per_decade: int = 2):
        self.alpha = float(alpha)
        self.parameters = (
            stiffness("k", "spring constant"),
            LinkParameter("c", "N s^alpha/m", f"springpot coefficient (alpha = {alpha:g})", 2.0 - alpha,
                          "eta_alpha", "Pa s^alpha", True, "fractional viscosity"),
        )
        self.r = np.logspace(-decades - 1, decades + 1, 2 * (decades + 1) * arms_per_decade + 1)
        x = np.logspace(-decades, decades, 40 * decades)
        target = (1j * x) ** alpha
        basis = (1j * x[:, None] * self.r) / (1 + 1j * x[:, None] * self.r) / np.abs(target)[:, None]
        rhs = target / np.abs(target)
        self.w, _ = nnls(np.vstack([basis.real, basis.imag]), np.concatenate([rhs.real, rhs.imag]), maxiter=10000)

    def matrices(self, p):
        k, c = p[0], p[1]
        w_c = (k / c) ** (1.0 / self.alpha)  # crossover frequency [rad/s]
        arms = [j for j in range(self.r.size) if self.w[j] > 0]
        n = len(arms)
        a = [[(-w_c / self.r[j]) if row == col else 0.0 for col in range(n)] for row, j in enumerate(arms)]
        return LinkMatrices(k=k, c=[k * self.w[j] for j in arms], a=a, f=[1.0] * n)

    def typical(self, k_ref, b_ref):
        return [k_ref, k_ref / (k_ref / b_ref) ** self.alpha]  # crossover where the KV one is


class FractionalKVOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    n_elements: int = Field(10, ge=1, le=200, description="number of elements n")
    alpha: float = Field(0.5, gt=0.05, lt=0.95, description="springpot order")
    decades: int = Field(2, ge=1, le=6, description="approximation band: +-decades around the crossover")
    arms_per_decade: int = Field(2, ge=1, le=4, description="Prony arms per decade")


class FractionalKelvinVoigtChain(ChainModel):
    """Chain with fractional Kelvin-Voigt normal links and Kelvin-Voigt shear links."""

    Options = FractionalKVOptions
    summary = "fractional Kelvin-Voigt chain (springpot as a Prony series; example plugin)"
    shear = KelvinVoigtLaw()

    def normal_law(self):
        o = self.options
        return _law(o.alpha, o.decades, o.arms_per_decade)


_LAWS: dict = {}


def _law(alpha, decades, arms_per_decade) -> FractionalKelvinVoigtLaw:
    """Laws are cached: the weight fit runs once per option set."""
    key = (alpha, decades, arms_per_decade)
    if key not in _LAWS:
        _LAWS[key] = FractionalKelvinVoigtLaw(*key)
    return _LAWS[key]


@hookimpl
def mbus_medium_models():
    return [MediumModelSpec("fractional_kv", FractionalKelvinVoigtChain, FractionalKelvinVoigtChain.summary)]
