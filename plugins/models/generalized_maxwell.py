"""Generalized-Maxwell (Prony-series) chain: normal links with K relaxation arms.

Geometry and masses as the Kelvin-Voigt chain (m = rho (pi D^2/4) L / n, end masses m/2).
Each normal link is an equilibrium spring k parallel to K Maxwell arms (k_j, b_j); arm j's
internal state is its spring elongation e_j [m]:

    F = k delta + sum_j k_j e_j,     e_j' = delta' - (k_j/b_j) e_j,     tau_j = b_j / k_j
    relaxation stiffness k(t) = k + sum_j k_j exp(-t/tau_j)   (a Prony series)

The shear link is Kelvin-Voigt by default (option ``shear_link``: ``generalized_maxwell``
uses the same K-arm law, or ``sls`` / ``maxwell``). With K = 1 the link is the standard
linear solid exactly. States z = [x, x', e_normal (K n), internal shear states].

Parameters (theta order) and time exponents (default K = 2, Kelvin-Voigt shear):

    k_sigma  [N/m]   normal equilibrium spring      e = 2
    k1_sigma [N/m], b1_sigma [N s/m], ..., kK_sigma, bK_sigma: the arms, e = 2 and 1
    k_tau    [N/m], b_tau [N s/m]: shear spring and dashpot, e = 2 and 1

Default bounds (0, inf). Properties with g_sigma = (L/n)/(pi D^2/4), g_tau = 1/(pi D):
E_sigma = g k_sigma [Pa], Ej_sigma = g kj_sigma [Pa], etaj_sigma = g bj_sigma [Pa s],
E_tau = k_tau/(pi D), eta_tau = b_tau/(pi D). Derived: relaxation times tau1_sigma <
tau2_sigma < ... [s] (sorted) and the unrelaxed modulus E0_sigma = E_sigma + sum Ej_sigma.

Initial values: half the typical stiffness in the equilibrium spring, the other half split
over arms with relaxation times a decade apart around 0.5 us, all moved along their time
exponents until the unrelaxed wave speed matches L / first-arrival time.
"""
from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.engine.chain import ChainModel, GeneralizedMaxwellLaw, KelvinVoigtLaw
from mbus_framework.interfaces.hookspecs import MediumModelSpec, hookimpl
from mbus_plugins.models.bounds import Elements


class GeneralizedMaxwellOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    n_elements: Elements = Field(10, description="number of elements n")
    n_arms: int = Field(2, ge=1, le=8, description="Maxwell arms K of the Prony series")
    shear_link: Literal["kelvin_voigt", "generalized_maxwell", "sls", "maxwell"] = Field(
        "kelvin_voigt", description="link law to the surroundings")


class GeneralizedMaxwellChain(ChainModel):
    """Chain of n masses joined by generalized-Maxwell (Prony series) links."""

    Options = GeneralizedMaxwellOptions
    summary = "generalized Maxwell (Prony series, K arms) chain, Kelvin-Voigt shear by default"
    shear = KelvinVoigtLaw()

    def normal_law(self):
        return GeneralizedMaxwellLaw(self.options.n_arms)


@hookimpl
def mbus_medium_models():
    return [MediumModelSpec("generalized_maxwell", GeneralizedMaxwellChain, GeneralizedMaxwellChain.summary)]
