"""Maxwell chain: the Kelvin-Voigt chain of eqs. 3.1-3.21 with Maxwell links (Fig. 2.2a).

Geometry and masses as the Kelvin-Voigt chain: n elements of m = rho (pi D^2/4) L / n [kg],
end masses m/2 (eq. 3.13). Every link is a spring k in series with a dashpot b. Its
internal state is the spring elongation e [m]:

    F = k e,        e' = delta' - (k/b) e,        F(s) = k b s / (b s + k) delta(s)

with delta the link's relative displacement (x_i - x_{i+1} between masses, x_n into the
receiver, x_i to the surroundings for shear links). The chain has states
z = [x', e_normal (n), e_shear (n)] (3n); no force depends on the absolute displacements,
so they are left out (a Maxwell medium is a fluid: no static stiffness). Output: the force
k_sigma e_n through the last normal link into the receiver.

Parameters (theta order) and time exponents (dynamics c times faster: value * c**e):

    k_sigma [N/m]   normal series spring          e = 2
    b_sigma [N s/m] normal series dashpot         e = 1
    k_tau   [N/m]   shear series spring            e = 2
    b_tau   [N s/m] shear series dashpot           e = 1

Default bounds (0, inf). Properties (eqs. 3.32-3.38 applied to each element):

    E_sigma = (L/n)/(pi D^2/4) k_sigma [Pa]    eta_sigma = (L/n)/(pi D^2/4) b_sigma [Pa s]
    E_tau   = k_tau / (pi D) [Pa]              eta_tau   = b_tau / (pi D) [Pa s]

and relaxation times tau_sigma = b_sigma/k_sigma = eta_sigma/E_sigma [s], likewise tau_tau
(``derived_properties``). Option ``shear_link`` swaps the shear law (e.g. ``kelvin_voigt``
for a Maxwell fluid column held by an elastic surround).

Initial values: typical E ~ 2 GPa, eta ~ 1 kPa s (tau = 0.5 us, inside the ultrasound band),
then every parameter is moved along its time exponent until the high-frequency wave speed
(L/n) sqrt(k_sigma/m) equals L / first-arrival time (Section 3.5.1).
"""
from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.engine.chain import ChainModel, MaxwellLaw
from mbus_framework.interfaces.hookspecs import MediumModelSpec, hookimpl
from mbus_plugins.models.bounds import Elements


class MaxwellOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    n_elements: Elements = Field(10, description="number of elements n")
    shear_link: Literal["same", "maxwell", "kelvin_voigt", "sls"] = Field(
        "same", description="link law to the surroundings ('same' = Maxwell)")


class MaxwellChain(ChainModel):
    """Chain of n masses joined by Maxwell links (spring in series with dashpot)."""

    Options = MaxwellOptions
    summary = "Maxwell chain: spring in series with dashpot (k_sigma, b_sigma, k_tau, b_tau)"
    normal = MaxwellLaw()
    shear = MaxwellLaw()


@hookimpl
def mbus_medium_models():
    return [MediumModelSpec("maxwell", MaxwellChain, MaxwellChain.summary)]
