"""Frequency responses of medium models (engine.frequency) against independent references."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from mbus_framework.engine.frequency import response, response_with_jacobian, tail_basis
from mbus_framework.engine.simulation import simulate
from mbus_framework.interfaces.sample import Sample
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from mbus_plugins.models.sls import SlsChain, SlsOptions


def kv(n=6, L=0.03, rho=1050.0, D=0.0254):
    return KelvinVoigtChain(Sample(L, D, rho), KelvinVoigtOptions(n_elements=n))


def theta_of(model, E_sigma, eta_sigma, E_tau, eta_tau):
    return np.asarray(model.from_properties(dict(E_sigma=E_sigma, eta_sigma=eta_sigma, E_tau=E_tau, eta_tau=eta_tau)))


# moduli, viscosities and element counts of real samples; shear within 1/100-100 x the normal
# modulus (a chain whose shear is 1e5 x stiffer transmits 1e-12 of the input: no record sees it)
materials = st.tuples(
    st.floats(1e8, 1e13), st.floats(1e1, 1e6), st.floats(-2.0, 2.0), st.floats(1e1, 1e6), st.integers(1, 12)
).map(lambda m: (m[0], m[1], m[0] * 10 ** m[2], m[3], m[4]))


@settings(max_examples=12, deadline=None)
@given(materials, st.sampled_from([None, 4e-8, 1.6e-7]))
@example((1e8, 10.0, 1e8, 271072.0, 12), 1.6e-7)  # a ZOH reference with round-off at 1.2e-8 of its peak
def test_response_matches_python_control(mat, dt):
    import control

    Es, es, Et, et, n = mat
    model = kv(n)
    theta = theta_of(model, Es, es, Et, et)
    f = np.logspace(3, 6.8, 40)
    A, B, C, D = (np.asarray(m, float) for m in model.state_space(theta))
    sys = control.ss(A, B, C, D)
    if dt is not None:
        sys = control.c2d(sys, dt, method="zoh")
        s = np.exp(2j * np.pi * f * dt)
    else:
        s = 2j * np.pi * f
    ref = np.array([complex(sys(sk)) for sk in s])
    got = response(model, theta, f, dt)
    # python-control's ZOH system (c2d through a matrix exponential) carries round-off of up to
    # about 1e-8 of the peak on soft, long chains (where the true response falls to 1e-47 it
    # gives 5e-19 against a peak of 5e-11); the continuous reference is exact to round-off
    tol = 1e-8 if dt is None else 1e-7
    assert np.max(np.abs(got - ref)) <= tol * np.max(np.abs(ref)) + 1e-300


@settings(max_examples=12, deadline=None)
@given(materials, st.sampled_from([None, 4e-8]))
@example((1e8, 10.0, 1e6, 805829.0, 2), None)  # the shear column at 4e-8 of the peak (a fresh-clone run)
def test_jacobian_matches_central_differences(mat, dt):
    Es, es, Et, et, n = mat
    model = kv(n)
    theta = theta_of(model, Es, es, Et, et)
    f = np.logspace(3.5, 6.5, 30)
    H, J = response_with_jacobian(model, theta, f, dt)
    # Central differences lose digits to truncation at sharp resonances (large steps) and to
    # round-off on columns far below the response (small steps): the exact column must match
    # them at one of five steps, to 1e-4 of the column's scale, on the lines a record can hold
    # (response within 120 dB of its peak; below that both are round-off) of media that transmit
    # something measurable (a peak transmission of 1e-6 of the input at least). Where a column
    # barely moves the response (a heavily damped shear link), both are compared to the peak: to
    # 1e-7 of it per unit relative change of the parameter, as the response itself is compared to
    # the ZOH reference above.
    assume(np.max(np.abs(H)) >= 1e-6)
    seen = np.abs(H) >= 1e-6 * np.max(np.abs(H))
    for i in range(theta.size):
        errors, scale = [], 0.0
        for rel in (1e-3, 1e-4, 1e-5, 1e-6, 1e-7):
            h = rel * theta[i]
            up, dn = theta.copy(), theta.copy()
            up[i] += h
            dn[i] -= h
            fd = (response(model, up, f, dt) - response(model, dn, f, dt)) / (2 * h)
            errors.append(np.max(np.abs(J[seen, i] - fd[seen])))
            scale = max(scale, np.max(np.abs(fd[seen])))
        assert min(errors) <= 1e-4 * scale + 1e-7 * np.max(np.abs(H)) / theta[i]


def test_jacobian_of_a_model_with_internal_states():
    model = SlsChain(Sample(0.02, 0.0254, 1000.0), SlsOptions(n_elements=4))
    theta = np.array([p.typical for p in model.parameters]) * np.linspace(0.7, 1.6, len(model.parameters))
    f = np.logspace(3.5, 6.5, 25)
    _, J = response_with_jacobian(model, theta, f, 5e-8)
    for i in range(theta.size):
        h = 1e-5 * theta[i]
        up, dn = theta.copy(), theta.copy()
        up[i] += h
        dn[i] -= h
        fd = (response(model, up, f, 5e-8) - response(model, dn, f, 5e-8)) / (2 * h)
        assert np.max(np.abs(J[:, i] - fd)) <= 1e-4 * (np.max(np.abs(fd)) + 1e-300)


def test_sampled_response_is_exact_on_the_lines_of_a_periodic_steady_state():
    model = kv(8)
    theta = theta_of(model, 2.4e10, 7.2e3, 6.6e9, 5.1e3)
    dt, P = 4e-8, 1000
    rng = np.random.default_rng(0)
    period = rng.choice([-1.0, 1.0], P)
    u = np.tile(period, 6)
    y = simulate(model, theta, u, dt)
    Y, U = np.fft.rfft(y[-P:]), np.fft.rfft(u[-P:])
    k = np.arange(1, P // 2)
    H = response(model, theta, k / (P * dt), dt)
    assert np.max(np.abs(Y[k] - H * U[k])) <= 1e-9 * np.max(np.abs(Y[k]))


def test_tail_basis_explains_the_end_of_a_record_exactly():
    """DTFT(record) = H(f) DTFT(u) - tail: the tail lies in the span of the basis."""
    from mbus_framework.estimation.spectral import dtft

    model = kv(5)
    theta = theta_of(model, 3e9, 150.0, 6e8, 150.0)  # lightly damped: rings past the record
    dt, N = 1.6e-7, 1500
    u = np.random.default_rng(1).choice([-1.0, 1.0], N)
    y = simulate(model, theta, u, dt)
    f = np.geomspace(2e3, 2e6, 150)
    lack = response(model, theta, f, dt) * dtft(u, f, dt) - dtft(y, f, dt)
    B = tail_basis(model, theta, f, dt, N)
    Br = np.vstack([B.real, B.imag])
    rhs = np.concatenate([lack.real, lack.imag])
    coef, *_ = np.linalg.lstsq(Br, rhs, rcond=None)
    assert np.linalg.norm(Br @ coef - rhs) <= 1e-8 * np.linalg.norm(rhs)
    assert np.linalg.norm(rhs) > 1e-3 * np.linalg.norm(dtft(y, f, dt))  # the tail is not negligible here


def test_time_scaling_is_a_frequency_shift():
    """theta * c**e runs the model c times faster: G_c(f) = G(f / c) (continuous)."""
    model = kv(6)
    theta = theta_of(model, 1e12, 3e5, 2e12, 5e5)
    e = np.array([p.time_exponent for p in model.parameters])
    f = np.logspace(4, 6.5, 20)
    c = 1.7
    assert response(model, theta * c**e, f) == pytest.approx(response(model, theta, f / c), rel=1e-10)


@pytest.mark.parametrize("dt", [None, 5e-8])
def test_direct_jacobian_agrees_with_the_modal_one(dt):
    """The adjoint direct-solve Jacobian (used where the modal sum is unsafe) against the modal
    Daleckii-Krein one on a well-conditioned chain with internal states."""
    from mbus_framework.engine.frequency import _direct_jacobian

    model = SlsChain(Sample(0.02, 0.0254, 1000.0), SlsOptions(n_elements=3))
    theta = np.array([p.typical for p in model.parameters]) * np.linspace(0.8, 1.3, len(model.parameters))
    f = np.logspace(3.5, 6.5, 25)
    H, J = response_with_jacobian(model, theta, f, dt)
    Hd, Jd = _direct_jacobian(model, theta, f, dt)
    assert np.max(np.abs(Hd - H)) <= 1e-9 * np.max(np.abs(H))
    for i in range(theta.size):
        assert np.max(np.abs(Jd[:, i] - J[:, i])) <= 1e-7 * np.max(np.abs(J[:, i]))


def test_kept_systems_do_not_mix_models_or_points():
    """The last few (model, theta) systems are kept: two chains at the same parameters, and
    one chain at two parameter vectors, each give their own response (python-control)."""
    import control

    f = np.logspace(4, 6.5, 15)
    a, b = kv(4), kv(7)
    th = theta_of(a, 2e9, 300.0, 8e8, 200.0)
    for model, theta in [(a, th), (b, th), (a, th * 1.3), (a, th), (b, th)]:
        A, B, C, D = (np.asarray(m, float) for m in model.state_space(theta))
        ref = np.array([complex(control.ss(A, B, C, D)(2j * np.pi * fk)) for fk in f])
        got = response(model, theta, f)
        assert np.max(np.abs(got - ref)) <= 1e-8 * np.max(np.abs(ref))
