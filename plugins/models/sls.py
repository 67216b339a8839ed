"""Standard-linear-solid (Zener) chain: eqs. 3.1-3.21 with SLS links (Fig. 2.2c).

Geometry and masses as the Kelvin-Voigt chain (m = rho (pi D^2/4) L / n, end masses m/2).
Every link is a spring k parallel to a Maxwell arm (spring k1 in series with dashpot b1);
the arm's internal state is its spring elongation e1 [m]:

    F = k delta + k1 e1,       e1' = delta' - (k1/b1) e1
    F(s) = [k + k1 b1 s / (b1 s + k1)] delta(s)

States z = [x (n), x' (n), e1_normal (n), e1_shear (n)] (4n); output k_sigma x_n +
k1_sigma e1_n, the force through the last normal link into the receiver.

Limits: k1 -> inf gives a Kelvin-Voigt link (k, b1); b1 -> inf a spring k + k1; b1 -> 0
a spring k (all tested).

Parameters (theta order) and time exponents:

    k_sigma  [N/m]   normal relaxed (equilibrium) spring   e = 2
    k1_sigma [N/m]   normal Maxwell-arm spring              e = 2
    b1_sigma [N s/m] normal Maxwell-arm dashpot             e = 1
    k_tau, k1_tau, b1_tau: the same for the shear links.

Default bounds (0, inf). Properties, with g_sigma = (L/n)/(pi D^2/4) and g_tau = 1/(pi D):

    E_sigma = g k_sigma (relaxed modulus) [Pa], E1_sigma = g k1_sigma [Pa],
    eta1_sigma = g b1_sigma [Pa s]; likewise E_tau, E1_tau, eta1_tau.

Derived (``derived_properties``): relaxation time tau_sigma = b1/k1 = eta1/E1 [s], unrelaxed
modulus E0_sigma = E_sigma + E1_sigma [Pa] (and for tau). Initial values: typical k = k1 =
half the Kelvin-Voigt typical stiffness, b1 = its typical damping, moved along the time
exponents until the unrelaxed wave speed (L/n) sqrt((k + k1)/m) matches L / arrival time.
"""
from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from mbus_framework.engine.chain import ChainModel, StandardLinearSolidLaw
from mbus_framework.interfaces.hookspecs import MediumModelSpec, hookimpl
from mbus_plugins.models.bounds import Elements


class SlsOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    n_elements: Elements = Field(10, description="number of elements n")
    shear_link: Literal["same", "sls", "kelvin_voigt", "maxwell"] = Field(
        "same", description="link law to the surroundings ('same' = SLS)")


class SlsChain(ChainModel):
    """Chain of n masses joined by standard-linear-solid (Zener) links."""

    Options = SlsOptions
    summary = "standard-linear-solid (Zener) chain (k, k1, b1 per direction)"
    normal = StandardLinearSolidLaw()
    shear = StandardLinearSolidLaw()


@hookimpl
def mbus_medium_models():
    return [MediumModelSpec("sls", SlsChain, SlsChain.summary)]
