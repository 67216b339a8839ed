"""Chain assembler and link laws (mbus_framework.engine.chain), and the contract suite's teeth."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mbus_framework.engine.chain import (
    ChainModel,
    ChainOptions,
    GeneralizedMaxwellLaw,
    KelvinVoigtLaw,
    LinkLaw,
    LinkMatrices,
    MaxwellLaw,
    StandardLinearSolidLaw,
    assemble_chain,
    damping,
    link_law,
    stiffness,
)
from mbus_framework.interfaces.sample import Sample
from mbus_framework.testing.models import MediumModelContract, response
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from mbus_plugins.models.maxwell import MaxwellChain, MaxwellOptions

TABLE_3_1 = Sample(length=0.05, diameter=0.0254, density=1000.0)
THETA_3_1 = np.array([3.0e8, 15.0, 5.0e7, 12.0])


def dissertation_kv(sample: Sample, n: int, k_s, b_s, k_t, b_t):
    """Eqs. 3.3-3.21 written out directly: M, B, K, B0 and C, A = [[0, I], [-M^-1 K, -M^-1 B]]."""
    m = sample.density * (np.pi * sample.diameter**2 / 4) * sample.length / n  # element mass (per-element rho)
    masses = np.full(n, m)
    masses[0] = masses[-1] = m / 2  # eq. 3.13
    M = np.diag(masses)  # eq. 3.3
    Bm = np.zeros((n, n))
    K = np.zeros((n, n))
    for i in range(n):  # eqs. 3.4-3.5: every mass has the link to its right (the last: to the wall)
        K[i, i] += k_s + k_t
        Bm[i, i] += b_s + b_t
        if i > 0:  # ... and, except the first, the link to its left
            K[i, i] += k_s
            Bm[i, i] += b_s
            K[i, i - 1] = K[i - 1, i] = -k_s
            Bm[i, i - 1] = Bm[i - 1, i] = -b_s
    Minv = np.diag(1.0 / np.diag(M))  # M is diagonal (eq. 3.3)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ Bm]])  # eq. 3.8
    B0 = np.zeros((n, 1))
    B0[0, 0] = 1.0  # eq. 3.6
    B = np.vstack([np.zeros((n, 1)), Minv @ B0])
    C = np.zeros((1, 2 * n))
    C[0, n - 1], C[0, 2 * n - 1] = k_s, b_s  # eq. 3.21
    return A, B, C, m


@pytest.mark.parametrize("n", [1, 2, 3, 10])
def test_kelvin_voigt_equals_dissertation_equations(n):
    model = KelvinVoigtChain(TABLE_3_1, KelvinVoigtOptions(n_elements=n))
    A, B, C, D = model.state_space(THETA_3_1)
    A_ref, B_ref, C_ref, m = dissertation_kv(TABLE_3_1, n, *THETA_3_1)
    np.testing.assert_allclose(A, A_ref, rtol=1e-14, atol=0)
    np.testing.assert_allclose(B, B_ref, rtol=1e-14, atol=0)
    np.testing.assert_array_equal(C, C_ref)
    np.testing.assert_array_equal(D, np.zeros((1, 1)))
    np.testing.assert_allclose(model.element_mass, m, rtol=1e-15)
    if n >= 3:  # eq. 3.18 entries and eq. 3.19
        k_s, b_s, k_t, b_t = THETA_3_1
        np.testing.assert_allclose(A[n, 0], -2 * (k_s + k_t) / m, rtol=1e-14)
        np.testing.assert_allclose(A[n + 1, 1], -(2 * k_s + k_t) / m, rtol=1e-14)
        np.testing.assert_allclose(A[2 * n - 1, n - 1], -2 * (2 * k_s + k_t) / m, rtol=1e-14)
        np.testing.assert_allclose(A[2 * n - 1, 2 * n - 1], -2 * (2 * b_s + b_t) / m, rtol=1e-14)
        np.testing.assert_allclose(A[2 * n - 1, 2 * n - 2], 2 * b_s / m, rtol=1e-14)
        np.testing.assert_allclose(B[n, 0], 2 / m, rtol=1e-14)


@settings(max_examples=30)
@given(n=st.integers(1, 25), logs=st.lists(st.floats(-3, 3), min_size=4, max_size=4))
def test_kelvin_voigt_identical_to_direct_construction(n, logs):
    """To round-off (a few ulps: the compiled assembly sums the same terms in another order):
    the assembler multiplies by 1/m as eq. 3.8's M^-1 (diagonal)."""
    theta = THETA_3_1 * np.exp(logs)
    model = KelvinVoigtChain(TABLE_3_1, KelvinVoigtOptions(n_elements=n))
    masses = model.masses()
    A, B, C, _ = model.state_space(theta)
    k_s, b_s, k_t, b_t = theta
    T = 2 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    T[0, 0] = 1.0
    K = k_s * T + k_t * np.eye(n)
    Bm = b_s * T + b_t * np.eye(n)
    Minv = np.diag(1.0 / masses)
    np.testing.assert_allclose(A[n:, :n], -(Minv @ K), rtol=1e-14, atol=0)
    np.testing.assert_allclose(A[n:, n:], -(Minv @ Bm), rtol=1e-14, atol=0)
    np.testing.assert_array_equal(A[:n, n:], np.eye(n))
    np.testing.assert_array_equal(B[n:, 0], Minv[:, 0])
    np.testing.assert_array_equal(C[0], np.r_[np.zeros(n - 1), k_s, np.zeros(n - 1), b_s])


def test_link_impedances_match_closed_forms():
    s = 1j * np.logspace(3, 8, 50)
    k, b, k1, b1, k2, b2 = 3e8, 15.0, 1e8, 300.0, 5e7, 20.0
    np.testing.assert_allclose(KelvinVoigtLaw().impedance([k, b], s), k + b * s, rtol=1e-13)
    np.testing.assert_allclose(MaxwellLaw().impedance([k, b], s), k * b * s / (b * s + k), rtol=1e-12)
    np.testing.assert_allclose(StandardLinearSolidLaw().impedance([k, k1, b1], s),
                               k + k1 * b1 * s / (b1 * s + k1), rtol=1e-12)
    np.testing.assert_allclose(GeneralizedMaxwellLaw(2).impedance([k, k1, b1, k2, b2], s),
                               k + k1 * b1 * s / (b1 * s + k1) + k2 * b2 * s / (b2 * s + k2), rtol=1e-12)
    assert StandardLinearSolidLaw().instantaneous_stiffness([k, k1, b1]) == k + k1
    assert MaxwellLaw().relaxation_times([k, b]) == {"tau": pytest.approx(b / k)}
    taus = GeneralizedMaxwellLaw(2).relaxation_times([k, k1, b1, k2, b2])
    assert list(taus) == ["tau1", "tau2"] and taus["tau1"] == pytest.approx(b2 / k2) and taus["tau2"] == pytest.approx(b1 / k1)


@pytest.mark.parametrize("law,p", [(KelvinVoigtLaw(), [2e8, 30.0]), (MaxwellLaw(), [2e8, 300.0]),
                                   (StandardLinearSolidLaw(), [1e8, 1e8, 200.0]),
                                   (GeneralizedMaxwellLaw(3), [1e8, 5e7, 10.0, 5e7, 100.0, 2e7, 1e3])])
def test_single_mass_against_wall_is_its_impedance(law, p):
    """One mass m between the source and the receiver: y/u = Z/(m s^2 + Z)."""
    m = 2e-3
    ss = assemble_chain([m], [law.matrices(p)], [None], np.asarray(p, float))
    s = 1j * np.logspace(4, 7, 40)
    Z = law.impedance(p, s)
    np.testing.assert_allclose(response(ss, s), Z / (m * s**2 + Z), rtol=1e-10)


def test_pure_maxwell_chain_drops_displacements():
    """No force depends on absolute positions, so the rigid-body integrators are left out."""
    m3 = MaxwellChain(TABLE_3_1, MaxwellOptions(n_elements=3))
    assert m3.n_states == 3 * 3
    theta = np.array([p.typical for p in m3.parameters])
    assert np.max(np.linalg.eigvals(m3.state_space(theta).A).real) < 0
    mixed = MaxwellChain(TABLE_3_1, MaxwellOptions(n_elements=3, shear_link="kelvin_voigt"))
    assert mixed.n_states == 2 * 3 + 3
    assert mixed.parameter_names == ["k_sigma", "b_sigma", "k_tau", "b_tau"]


def test_link_law_by_name_suggests():
    assert isinstance(link_law("sls"), StandardLinearSolidLaw)
    assert link_law("generalized_maxwell", 3).n_arms == 3
    with pytest.raises(ValueError, match="did you mean 'maxwell'"):
        link_law("maxwel")
    with pytest.raises(ValueError):
        GeneralizedMaxwellLaw(0)


def test_assembler_rejects_mismatched_links():
    lm = KelvinVoigtLaw().matrices([1.0, 1.0])
    with pytest.raises(ValueError):
        assemble_chain([1.0, 1.0], [lm], [None, None], np.ones(2))


# -- the contract suite must catch broken models --------------------------------------------

SMALL = Sample(length=0.02, diameter=0.0254, density=1000.0)


class _NegativeDashpot(LinkLaw):
    """Spring parallel to a *negative* dashpot: creates energy."""

    name = "negative"
    parameters = (stiffness("k", "spring"), damping("b", "dashpot"))

    def matrices(self, p):
        return LinkMatrices(k=p[0], b=-p[1])

    def typical(self, k_ref, b_ref):
        return [k_ref, b_ref]


class _AbsMaxwell(MaxwellLaw):
    """Uses abs(): not analytic, breaks complex-step derivatives."""

    def matrices(self, p):
        return LinkMatrices(c=[p[0]], a=[[-abs(p[0]) / p[1]]], f=[1.0])


def _chain(normal, shear=KelvinVoigtLaw()):
    cls = type("BrokenChain", (ChainModel,), {"normal": normal, "shear": shear, "summary": "broken"})
    return cls(SMALL, ChainOptions(n_elements=2))


def _contract(models):
    class _C(MediumModelContract):
        def make_models(self):
            return models

    return _C()


def test_contract_catches_energy_creation():
    c = _contract([_chain(_NegativeDashpot(), _NegativeDashpot())])
    with pytest.raises(AssertionError):
        c.test_passive()
    with pytest.raises(AssertionError):
        c.test_poles_stable()


def test_contract_catches_non_analytic_model():
    with pytest.raises(AssertionError, match="complex"):
        _contract([_chain(_AbsMaxwell())]).test_complex_step_matches_finite_difference()


def test_contract_catches_wrong_time_exponent():
    from dataclasses import replace

    law = MaxwellLaw()
    law.parameters = (law.parameters[0], replace(law.parameters[1], time_exponent=2.0))
    with pytest.raises(AssertionError, match="time_exponent"):
        _contract([_chain(law)]).test_time_exponents()


def test_contract_catches_bad_property_inverse():
    class BadInverse(KelvinVoigtChain):
        def from_properties(self, properties):
            return super().from_properties(properties) * 1.001

    with pytest.raises(AssertionError):
        _contract([BadInverse(SMALL, KelvinVoigtOptions(n_elements=2))]).test_property_roundtrip()
