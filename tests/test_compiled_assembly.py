"""The compiled chain assembly (a linear map of the link coefficients, issue 24) equals the
element-by-element assembly of :func:`assemble_chain` for every chain model and link law,
for float and complex (complex-step) parameters."""
import numpy as np
import pytest

from mbus_framework.engine.simulation import state_space_derivatives
from mbus_framework.interfaces.sample import Sample
from mbus_plugins.models.generalized_maxwell import GeneralizedMaxwellChain, GeneralizedMaxwellOptions
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from mbus_plugins.models.maxwell import MaxwellChain, MaxwellOptions
from mbus_plugins.models.sls import SlsChain, SlsOptions

SAMPLE = Sample(0.03, 0.0254, 1080.0)
MODELS = [
    KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=6)),
    MaxwellChain(SAMPLE, MaxwellOptions(n_elements=5)),
    MaxwellChain(SAMPLE, MaxwellOptions(n_elements=4, shear_link="kelvin_voigt")),
    SlsChain(SAMPLE, SlsOptions(n_elements=5)),
    SlsChain(SAMPLE, SlsOptions(n_elements=3, shear_link="maxwell")),
    GeneralizedMaxwellChain(SAMPLE, GeneralizedMaxwellOptions(n_elements=4, n_arms=3)),
    GeneralizedMaxwellChain(SAMPLE, GeneralizedMaxwellOptions(n_elements=3, n_arms=2, shear_link="generalized_maxwell")),
]


def _theta(model, seed):
    typical = np.array([p.typical for p in model.parameters], dtype=float)
    return typical * np.exp(np.random.default_rng(seed).uniform(-1, 1, typical.size))


def _reference(model, theta):
    """The element-by-element assembly (the generic path, as for CasADi parameters)."""
    return model._assemble(model._link_matrices(theta), theta)


@pytest.mark.parametrize("model", MODELS, ids=lambda m: f"{type(m).__name__}")
def test_compiled_equals_element_assembly(model):
    for seed in range(3):
        theta = _theta(model, seed)
        for th in (theta, theta.astype(complex) + 1j * 1e-20 * theta * (np.arange(theta.size) == seed % theta.size)):
            fast, ref = model.state_space(th), _reference(model, th)
            for a, b in zip(fast, ref):
                a, b = np.asarray(a), np.asarray(b, dtype=a.dtype)
                assert a.shape == b.shape and a.dtype == b.dtype
                np.testing.assert_allclose(a.real, b.real, rtol=1e-14, atol=1e-14 * np.abs(b).max())
                np.testing.assert_allclose(a.imag, b.imag, rtol=1e-14, atol=1e-14 * np.abs(b.imag).max())


def test_compiled_derivatives_match_central_differences():
    model = MODELS[3]
    theta = _theta(model, 7)
    dss = state_space_derivatives(model, theta)
    for p in range(theta.size):
        h = 1e-6 * theta[p]
        up, dn = theta.copy(), theta.copy()
        up[p] += h
        dn[p] -= h
        fd = (np.asarray(model.state_space(up)[0]) - np.asarray(model.state_space(dn)[0])) / (2 * h)
        np.testing.assert_allclose(dss[p].A, fd, rtol=1e-6, atol=1e-8 * np.abs(fd).max())


def test_non_finite_parameters_use_the_element_assembly():
    model = MODELS[0]
    theta = _theta(model, 1)
    theta[1] = np.nan
    A = np.asarray(model.state_space(theta).A)
    assert np.isnan(A).any() and np.isfinite(A).any()  # NaN only where the coefficient enters
