"""Kelvin-Voigt chain (eqs. 3.1-3.21, 3.32-3.38): matrices, poles, static gain, properties.

References are independent of the model code: K and B are rebuilt here from eqs. 3.4/3.5 with
eqs. 3.13-3.17 (k_sigma T + k_tau I, T = tridiag(-1, 2, -1) with T[0,0] = 1), eq. 3.18 is typed
in entry by entry for n = 4, poles come from python-control and are checked against a bound
derived from the quadratic eigenvalue problem, and the static gain of the chain without shear
is exactly 1 (every newton of the input reaches the receiver).
"""
from __future__ import annotations

import math

import control
import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from mbus_framework.interfaces.sample import Sample
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

NAMES = ["k_sigma", "b_sigma", "k_tau", "b_tau"]


def log_uniform(lo: float, hi: float):
    """Floats spread evenly in log10 between lo and hi (positive)."""
    return st.floats(math.log10(lo), math.log10(hi), allow_nan=False, allow_infinity=False).map(lambda e: 10.0**e)


geometries = st.tuples(
    log_uniform(1e-3, 0.2),  # L [m]
    log_uniform(5e-3, 0.05),  # D [m]
    log_uniform(100.0, 3000.0),  # rho [kg/m^3]
    st.integers(1, 40),  # n
)
parameters = st.tuples(
    log_uniform(1e5, 1e11),  # k_sigma [N/m]
    log_uniform(1e-2, 1e4),  # b_sigma [N s/m]
    log_uniform(1e3, 1e10),  # k_tau [N/m]
    log_uniform(1e-2, 1e4),  # b_tau [N s/m]
)


def chain(L: float, D: float, rho: float, n: int) -> KelvinVoigtChain:
    return KelvinVoigtChain(Sample(L, D, rho), KelvinVoigtOptions(n_elements=n))


def tridiag_T(n: int) -> np.ndarray:
    """Connectivity of the normal links (eqs. 3.4/3.5 with equal links): one link on mass 1,
    two on every other mass (the last one's second link goes to the receiver wall)."""
    T = 2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    T[0, 0] = 1.0
    return T


def reference_masses(L: float, D: float, rho: float, n: int) -> np.ndarray:
    m = rho * (math.pi * D**2 / 4.0) * L / n
    out = np.full(n, m)
    out[0] = out[-1] = m / 2.0
    return out


def blocks(model: KelvinVoigtChain, theta):
    """K = -M A[n:, :n] and Bdamp = -M A[n:, n:] recovered from the state matrix."""
    A, B, C, D = (np.asarray(x, dtype=float) for x in model.state_space(np.asarray(theta, dtype=float)))
    n = model.n
    M = np.diag(model.masses())
    return A, B, C, D, -M @ A[n:, :n], -M @ A[n:, n:]


def static_gain(model: KelvinVoigtChain, theta) -> float:
    """G(0) = D - C A^-1 B of the continuous system."""
    A, B, C, D = (np.asarray(x, dtype=float) for x in model.state_space(np.asarray(theta, dtype=float)))
    return float(D[0, 0] - (C @ np.linalg.solve(A, B))[0, 0])


# ---------------------------------------------------------------------------------------
# Property tests over random positive parameters and geometries
# ---------------------------------------------------------------------------------------
@given(geometries, parameters)
def test_stiffness_and_damping_matrices_are_symmetric_positive_definite(geom, theta):
    L, D, rho, n = geom
    model = chain(*geom)
    A, B, C, Dm, K, Bd = blocks(model, theta)
    k_s, b_s, k_t, b_t = theta
    assert A.shape == (2 * n, 2 * n) and B.shape == (2 * n, 1) and C.shape == (1, 2 * n) and Dm.shape == (1, 1)
    # Upper half of eq. 3.8: dx/dt = v.
    np.testing.assert_array_equal(A[:n, :n], 0.0)
    np.testing.assert_array_equal(A[:n, n:], np.eye(n))
    # Symmetric ...
    np.testing.assert_allclose(K, K.T, rtol=1e-12, atol=1e-12 * np.abs(K).max())
    np.testing.assert_allclose(Bd, Bd.T, rtol=1e-12, atol=1e-12 * np.abs(Bd).max())
    # ... equal to eqs. 3.4/3.5 with eqs. 3.14-3.17 ...
    T = tridiag_T(n)
    np.testing.assert_allclose(K, k_s * T + k_t * np.eye(n), rtol=1e-10, atol=1e-12 * k_s)
    np.testing.assert_allclose(Bd, b_s * T + b_t * np.eye(n), rtol=1e-10, atol=1e-12 * b_s)
    # ... and positive definite (Cholesky succeeds, smallest eigenvalue > 0).
    np.linalg.cholesky(0.5 * (K + K.T))
    np.linalg.cholesky(0.5 * (Bd + Bd.T))
    assert np.linalg.eigvalsh(0.5 * (K + K.T)).min() > 0
    assert np.linalg.eigvalsh(0.5 * (Bd + Bd.T)).min() > 0


@given(geometries, parameters)
def test_input_output_and_mass_matrices(geom, theta):
    L, D, rho, n = geom
    model = chain(*geom)
    A, B, C, Dm, _, _ = blocks(model, theta)
    masses = reference_masses(*geom)
    np.testing.assert_allclose(model.masses(), masses, rtol=1e-12)
    # Eq. 3.12/3.19: force on mass 1 only, 1/m_1 (= 2/m for n > 1).
    expected_B = np.zeros((2 * n, 1))
    expected_B[n, 0] = 1.0 / masses[0]
    np.testing.assert_allclose(B, expected_B, rtol=1e-12)
    # Eq. 3.21: y = k_sigma x_n + b_sigma v_n.
    expected_C = np.zeros((1, 2 * n))
    expected_C[0, n - 1] = theta[0]
    expected_C[0, 2 * n - 1] = theta[1]
    np.testing.assert_allclose(C, expected_C, rtol=1e-12)
    assert Dm[0, 0] == 0.0


@given(geometries, parameters)
def test_all_poles_in_open_left_half_plane(geom, theta):
    """Poles from python-control, and a quantitative margin from the quadratic eigenproblem.

    For an eigenpair (lambda, v) of lambda^2 M + lambda B + K: complex lambda has
    Re = -v*Bv / (2 v*Mv) <= -lmin(B) / (2 max m); real lambda lies at or left of
    -v*Kv / v*Bv <= -lmin(K) / lmax(B). So every pole has Re <= -min of the two.
    """
    model = chain(*geom)
    A, B, C, D, K, Bd = blocks(model, theta)
    poles = control.ss(A, B, C, D).poles()
    assert poles.size == 2 * model.n
    assert np.all(poles.real < 0), poles[poles.real >= 0]
    eK, eB = np.linalg.eigvalsh(K), np.linalg.eigvalsh(Bd)
    margin = min(eB.min() / (2.0 * model.masses().max()), eK.min() / eB.max())
    assert poles.real.max() <= -0.5 * margin


@given(geometries, parameters)
def test_static_gain_is_one_without_shear(geom, theta):
    """k_tau = b_tau = 0: nothing leaks to the surroundings, so all force reaches the receiver."""
    model = chain(*geom)
    theta = (theta[0], theta[1], 0.0, 0.0)
    assert static_gain(model, theta) == pytest.approx(1.0, abs=1e-9)
    A, B, C, D = model.state_space(np.asarray(theta, dtype=float))
    assert float(np.real(control.dcgain(control.ss(A, B, C, D)))) == pytest.approx(1.0, abs=1e-8)


@given(geometries, parameters)
def test_static_gain_below_one_and_falling_with_shear_stiffness(geom, theta):
    model = chain(*geom)
    k_s, b_s, _, b_t = theta
    ratios = np.array([1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0])
    gains = np.array([static_gain(model, (k_s, b_s, r * k_s, b_t)) for r in ratios])
    assert np.all(gains < 1.0) and np.all(gains > 0.0), gains
    assert np.all(np.diff(gains) < 0), gains
    # Independent reference: static deflection K x = e_1, y = k_sigma x_n.
    n = model.n
    for r, g in zip(ratios, gains):
        K = k_s * tridiag_T(n) + r * k_s * np.eye(n)
        x = np.linalg.solve(K, np.eye(n)[:, 0])
        assert g == pytest.approx(k_s * x[-1], rel=1e-8)
    # The static gain does not depend on the dashpots.
    assert static_gain(model, (k_s, 3 * b_s, 0.1 * k_s, 7 * b_t)) == pytest.approx(gains[3], rel=1e-9)


@given(geometries, parameters, st.floats(0.1, 10.0))
def test_time_exponents_make_the_dynamics_run_faster(geom, theta, c):
    """The strategy relies on it: theta_i * c**e_i multiplies every pole by c, gain unchanged."""
    model = chain(*geom)
    e = np.array([p.time_exponent for p in model.parameters])
    theta = np.asarray(theta, dtype=float)
    p1 = c * np.linalg.eigvals(np.asarray(model.state_space(theta).A, float))
    p2 = np.linalg.eigvals(np.asarray(model.state_space(theta * c**e).A, float))
    tol = 1e-6 * np.abs(p1).max()
    # Same set of poles: every pole of one system has a partner in the other.
    assert np.abs(p1[:, None] - p2[None, :]).min(axis=1).max() <= tol
    assert np.abs(p1[:, None] - p2[None, :]).min(axis=0).max() <= tol
    assert static_gain(model, theta * c**e) == pytest.approx(static_gain(model, theta), rel=1e-7)


# ---------------------------------------------------------------------------------------
# Eq. 3.18 by hand, masses, metadata
# ---------------------------------------------------------------------------------------
def test_eq_3_18_entries_for_four_elements():
    L, D, rho, n = 0.04, 0.02, 1250.0, 4
    m = rho * math.pi * D**2 / 4 * L / n  # eq. 3.13 per element
    ks, bs, kt, bt = 3.0e8, 15.0, 5.0e7, 12.0
    model = chain(L, D, rho, n)
    A, B, C, Dm = (np.asarray(x, dtype=float) for x in model.state_space(np.array([ks, bs, kt, bt])))
    Z = 0.0
    # Rows typed from eq. 3.18 (columns x1..x4, v1..v4).
    expected = np.array(
        [
            [Z, Z, Z, Z, 1, Z, Z, Z],
            [Z, Z, Z, Z, Z, 1, Z, Z],
            [Z, Z, Z, Z, Z, Z, 1, Z],
            [Z, Z, Z, Z, Z, Z, Z, 1],
            [-2 * (ks + kt) / m, 2 * ks / m, Z, Z, -2 * (bs + bt) / m, 2 * bs / m, Z, Z],
            [ks / m, -(2 * ks + kt) / m, ks / m, Z, bs / m, -(2 * bs + bt) / m, bs / m, Z],
            [Z, ks / m, -(2 * ks + kt) / m, ks / m, Z, bs / m, -(2 * bs + bt) / m, bs / m],
            [Z, Z, 2 * ks / m, -2 * (2 * ks + kt) / m, Z, Z, 2 * bs / m, -2 * (2 * bs + bt) / m],
        ]
    )
    np.testing.assert_allclose(A, expected, rtol=1e-13, atol=0)
    np.testing.assert_allclose(B[:, 0], [0, 0, 0, 0, 2 / m, 0, 0, 0], rtol=1e-13)  # eq. 3.19
    np.testing.assert_allclose(C[0], [0, 0, 0, ks, 0, 0, 0, bs], rtol=1e-13)  # eq. 3.21
    assert Dm[0, 0] == 0


def test_single_element_is_one_half_mass_on_two_springs():
    """n = 1: one mass m/2 tied to the receiver by the normal link and to ground by the shear link."""
    L, D, rho = 0.01, 0.0254, 1000.0
    m = rho * math.pi * D**2 / 4 * L
    ks, bs, kt, bt = 2e8, 10.0, 3e7, 4.0
    A, B, C, Dm = (np.asarray(x, float) for x in chain(L, D, rho, 1).state_space(np.array([ks, bs, kt, bt])))
    np.testing.assert_allclose(A, [[0, 1], [-(ks + kt) / (m / 2), -(bs + bt) / (m / 2)]], rtol=1e-13)
    np.testing.assert_allclose(B[:, 0], [0, 2 / m], rtol=1e-13)
    np.testing.assert_allclose(C[0], [ks, bs], rtol=1e-13)


@pytest.mark.parametrize("n", [2, 3, 10, 40])
def test_masses_are_half_at_the_ends(n):
    L, D, rho = 0.03, 0.0254, 1080.0
    model = chain(L, D, rho, n)
    m = rho * math.pi * D**2 / 4 * L / n
    masses = model.masses()
    assert masses[0] == pytest.approx(m / 2, rel=1e-12)
    assert masses[-1] == pytest.approx(m / 2, rel=1e-12)
    np.testing.assert_allclose(masses[1:-1], m, rtol=1e-12)
    assert masses.sum() == pytest.approx((n - 1) * m, rel=1e-12)


def test_parameter_and_property_names_units_and_time_exponents():
    model = chain(0.05, 0.0254, 1000.0, 10)
    assert model.parameter_names == NAMES
    assert model.property_names == ["E_sigma", "eta_sigma", "E_tau", "eta_tau"]
    assert [p.unit for p in model.parameters] == ["N/m", "N s/m", "N/m", "N s/m"]
    assert [p.unit for p in model.properties] == ["Pa", "Pa s", "Pa", "Pa s"]
    assert [p.time_exponent for p in model.parameters] == [2.0, 1.0, 2.0, 1.0]
    assert all(p.lower == 0.0 and p.typical > 0 for p in model.parameters)


def test_n_elements_option_is_validated():
    from pydantic import ValidationError

    for bad in (0, -3):
        with pytest.raises(ValidationError):
            KelvinVoigtOptions(n_elements=bad)
    assert KelvinVoigtOptions().n_elements == 10


# ---------------------------------------------------------------------------------------
# Material properties, eqs. 3.32-3.38
# ---------------------------------------------------------------------------------------
def test_properties_by_hand_for_table_3_1():
    """Table 3.1 geometry: L = 0.05 m, D = 0.0254 m, n = 10."""
    L, D, n = 0.05, 0.0254, 10
    model = chain(L, D, 1000.0, n)
    props = model.to_properties(np.array([3.0e8, 15.0, 5.0e7, 12.0]))
    area = math.pi * D**2 / 4
    assert props["E_sigma"] == pytest.approx((L / n) / area * 3.0e8, rel=1e-14)  # eq. 3.32
    assert props["eta_sigma"] == pytest.approx((L / n) / area * 15.0, rel=1e-14)  # eq. 3.36
    assert props["E_tau"] == pytest.approx(5.0e7 / (math.pi * D), rel=1e-14)  # eq. 3.37
    assert props["eta_tau"] == pytest.approx(12.0 / (math.pi * D), rel=1e-14)  # eq. 3.38
    # Numbers worked out by hand: (0.005 m / 5.0671e-4 m^2) * 3e8 N/m = 2.9603e9 Pa, ...
    assert props["E_sigma"] == pytest.approx(2.9603e9, rel=1e-4)
    assert props["eta_sigma"] == pytest.approx(148.01, rel=1e-4)
    assert props["E_tau"] == pytest.approx(6.2659e8, rel=1e-4)
    assert props["eta_tau"] == pytest.approx(150.38, rel=1e-4)


def test_potato_truth_in_parameters():
    """configs/potato.yaml truth (Table 6.2) converts to the parameters a user would expect."""
    L, D, n = 0.03, 0.0254, 10
    model = chain(L, D, 1080.0, n)
    theta = model.from_properties({"E_sigma": 2.42e10, "eta_sigma": 7.18e3, "E_tau": 6.56e9, "eta_tau": 5.14e3})
    area = math.pi * D**2 / 4
    np.testing.assert_allclose(
        theta, [2.42e10 * area / (L / n), 7.18e3 * area / (L / n), 6.56e9 * math.pi * D, 5.14e3 * math.pi * D], rtol=1e-14
    )


@given(geometries, parameters)
def test_property_round_trip(geom, theta):
    model = chain(*geom)
    theta = np.asarray(theta, dtype=float)
    props = model.to_properties(theta)
    assert set(props) == {"E_sigma", "eta_sigma", "E_tau", "eta_tau"}
    np.testing.assert_allclose(model.from_properties(props), theta, rtol=1e-13)
    # ... and the other way round.
    again = model.to_properties(model.from_properties(props))
    for k in props:
        assert again[k] == pytest.approx(props[k], rel=1e-13)


@given(geometries, parameters)
def test_properties_do_not_depend_on_n_for_the_same_material(geom, theta):
    """Refining the mesh keeps the material: k_sigma scales with n (shorter elements are stiffer),
    the shear coefficients are per element and stay put (eqs. 3.32-3.38)."""
    L, D, rho, n = geom
    assume(n <= 20)
    coarse, fine = chain(L, D, rho, n), chain(L, D, rho, 2 * n)
    props = coarse.to_properties(np.asarray(theta, float))
    theta_fine = fine.from_properties(props)
    np.testing.assert_allclose(theta_fine, np.asarray(theta) * [2, 2, 1, 1], rtol=1e-13)


def test_theta_from_mapping_accepts_parameters_or_properties():
    model = chain(0.05, 0.0254, 1000.0, 10)
    theta = np.array([3.0e8, 15.0, 5.0e7, 12.0])
    np.testing.assert_array_equal(model.theta_from_mapping(dict(zip(NAMES, theta)), "x"), theta)
    np.testing.assert_allclose(model.theta_from_mapping(model.to_properties(theta), "x"), theta, rtol=1e-14)
