"""Engine tests: exactness of both kernel paths, path selection, sensitivities, invariances.

References implemented elsewhere (python-control, scipy.signal, CasADi CVODES) are in
``test_simulation_references.py``; this file checks the engine against itself in ways
that can fail: the modal formulas against the eigen-free doubling path, the phi-functions
against mpmath, sensitivities against central finite differences, and the linear-system
invariances (superposition, time shift) on the sampled output.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mbus_framework.engine import modal_response, simulation as sim
from mbus_framework.engine.arrays import zeros_like_params
from mbus_framework.interfaces.model import MediumModel, Parameter, Property, StateSpace
from mbus_framework.interfaces.sample import Sample
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

TABLE_3_1 = np.array([3.0e8, 15.0, 5.0e7, 12.0])  # k_sigma, b_sigma, k_tau, b_tau
SAMPLE = Sample(length=0.05, diameter=0.0254, density=1000.0)
DT = 1.0 / 6.25e6


def kv(n: int = 10) -> KelvinVoigtChain:
    return KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=n))


def prbs_like(rng: np.random.Generator, N: int, hold: int = 16) -> np.ndarray:
    """A +-1 random telegraph signal with bits of ``hold`` samples (starts non-zero)."""
    bits = rng.choice([-1.0, 1.0], size=-(-N // hold))
    return np.repeat(bits, hold)[:N]


def rel(a, b) -> float:
    """max |a - b| / max |b| (b the reference)."""
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def col_rel(a, b) -> float:
    """Worst column-wise relative difference of two Jacobians (N, p)."""
    return max(rel(a[:, i], b[:, i]) for i in range(b.shape[1]))


# ---------------------------------------------------------------------------------------
# Small test models written like plugins (arithmetic only, so complex step works)
# ---------------------------------------------------------------------------------------
@dataclass
class _TinyModel(MediumModel):
    """Shared boilerplate: parameters named p0.., no material properties."""

    n_params = 2

    @property
    def parameters(self):
        return tuple(Parameter(f"p{i}", "-", "test", 0.0, np.inf, 1.0) for i in range(self.n_params))

    @property
    def properties(self):
        return (Property("none", "-", "test"),)

    def to_properties(self, theta):
        return {"none": 0.0}

    def from_properties(self, properties):
        return np.ones(self.n_params)


@dataclass
class JordanModel(_TinyModel):
    """A = a (J - I), J the upper shift: one eigenvalue -a of multiplicity ``size``, a single
    Jordan block (defective). B = g e_last, C = e_1: transfer g a^(m-1) / (s + a)^m.

    theta = [a (1/s), g (gain)]."""

    size: int = 3

    def state_space(self, theta) -> StateSpace:
        a, g = theta[0], theta[1]
        m = self.size
        A = zeros_like_params((m, m), theta)
        for i in range(m):
            A[i, i] = -a
            if i + 1 < m:
                A[i, i + 1] = a
        B = zeros_like_params((m, 1), theta)
        B[m - 1, 0] = g
        C = zeros_like_params((1, m), theta)
        C[0, 0] = 1.0
        D = zeros_like_params((1, 1), theta)
        return StateSpace(A, B, C, D)


@dataclass
class NearDefectiveModel(_TinyModel):
    """A = a [[-1, 1], [eps, -1]]: eigenvalues -a (1 -+ sqrt(eps)), defective as eps -> 0.

    theta = [a (1/s), eps (-)]; B = [0, 1], C = [1, 0.5], D = 0.1 (a direct feed-through)."""

    def state_space(self, theta) -> StateSpace:
        a, eps = theta[0], theta[1]
        A = zeros_like_params((2, 2), theta)
        A[0, 0] = -a
        A[0, 1] = a
        A[1, 0] = eps * a
        A[1, 1] = -a
        B = zeros_like_params((2, 1), theta)
        B[1, 0] = 1.0 + 0.0 * a
        C = zeros_like_params((1, 2), theta)
        C[0, 0] = 1.0
        C[0, 1] = 0.5
        D = zeros_like_params((1, 1), theta)
        D[0, 0] = 0.1 + 0.0 * a
        return StateSpace(A, B, C, D)


@dataclass
class TwinModel(_TinyModel):
    """Two identical, uncoupled damped oscillators: A normal-ish with each eigenvalue
    repeated (diagonalisable, not defective). theta = [w (rad/s), zeta (-)]."""

    def state_space(self, theta) -> StateSpace:
        w, z = theta[0], theta[1]
        A = zeros_like_params((4, 4), theta)
        for o in (0, 2):
            A[o, o + 1] = 1.0
            A[o + 1, o] = -w * w
            A[o + 1, o + 1] = -2.0 * z * w
        B = zeros_like_params((4, 1), theta)
        B[1, 0] = w * w
        B[3, 0] = 0.5 * w * w
        C = zeros_like_params((1, 4), theta)
        C[0, 0] = 1.0
        C[0, 2] = -1.0
        D = zeros_like_params((1, 1), theta)
        return StateSpace(A, B, C, D)


TINY = Sample(0.01, 0.01, 1000.0)


# ---------------------------------------------------------------------------------------
# phi-functions
# ---------------------------------------------------------------------------------------
def test_phi_functions_match_mpmath():
    mp = pytest.importorskip("mpmath")
    mp.mp.dps = 100  # the reference subtracts a Taylor head: needs digits for |z| ~ 1e-9
    rng = np.random.default_rng(1)
    mag = 10 ** rng.uniform(-9, 3, 300)
    z = mag * np.exp(1j * rng.uniform(-np.pi, np.pi, 300))
    z = z[z.real < 600]  # e^z overflows beyond ~709; such modes never take the modal path
    z = np.concatenate([z, [0.0, 1.0, -1.0, 1j, 0.999999, -1.000001, -700.0, 40j, -1e4 + 1e5j]])
    phis = sim.phi_functions(z)
    for k, values in enumerate(phis, start=1):
        worst = 0.0
        for zi, v in zip(z, values):
            zm = mp.mpc(zi.real, zi.imag)
            if zm == 0:
                exact = 1 / mp.factorial(k)
            else:
                exact = (mp.exp(zm) - sum(zm**j / mp.factorial(j) for j in range(k))) / zm**k
            worst = max(worst, float(abs(mp.mpc(v.real, v.imag) - exact) / abs(exact)))
        assert worst < 1e-14, (k, worst)


# ---------------------------------------------------------------------------------------
# Modal path == doubling path (two independent derivations of the same exact kernels)
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("hold", ["zoh", "foh"])
@pytest.mark.parametrize("n", [1, 2, 10, 40])
def test_modal_equals_doubling_kelvin_voigt(n, hold):
    model = kv(n)
    u = prbs_like(np.random.default_rng(n), 3000)
    ss = model.state_space(TABLE_3_1)
    assert sim.engine_path(ss, DT, sensitivities=True) == "modal"
    y_m, J_m = sim.simulate_with_sensitivities(model, TABLE_3_1, u, DT, hold, method="modal")
    y_d, J_d = sim.simulate_with_sensitivities(model, TABLE_3_1, u, DT, hold, method="doubling")
    assert rel(y_m, y_d) < 1e-11
    assert col_rel(J_m, J_d) < 1e-10
    # simulate() and the y of simulate_with_sensitivities() are the same numbers
    assert rel(sim.simulate(model, TABLE_3_1, u, DT, hold), y_d) < 1e-11


def test_markov_parameters_modal_vs_discretize():
    """The modal kernel g[m] equals C Phi^(m-1) Gamma from the Van Loan matrix exponential."""
    ss = sim.as_float_ss(kv(5).state_space(TABLE_3_1))
    for hold in ("zoh", "foh"):
        g_m, c_m, _, _ = modal_response.modal_kernels(sim.modal_form(ss), DT, hold, 500)
        d = sim.discretize(ss, DT, hold)
        g_ref = sim.markov_parameters(d, 500)
        assert rel(g_m[0], g_ref) < 1e-12
        if hold == "foh":
            Phi_k = np.eye(d.Phi.shape[0])
            ref = []
            for _ in range(500):
                ref.append(d.C @ Phi_k @ d.Gamma1)
                Phi_k = Phi_k @ d.Phi
            assert rel(c_m[0], np.array(ref)) < 1e-11


# ---------------------------------------------------------------------------------------
# Defective, near-defective, repeated, stiff and lightly damped models
# ---------------------------------------------------------------------------------------
def _zoh_recursion(ss: StateSpace, u: np.ndarray, dt: float) -> np.ndarray:
    """Plain per-sample recursion with Phi, Gamma from scipy's expm (independent of the engine)."""
    from scipy.linalg import expm

    A, B, C, D = (np.atleast_2d(np.asarray(m, float)) for m in ss)
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n:] = A * dt, B * dt
    E = expm(M)
    Phi, Gam = E[:n, :n], E[:n, n]
    x = np.zeros(n)
    y = np.empty(u.size)
    for k, uk in enumerate(u):
        y[k] = C[0] @ x + D[0, 0] * uk
        x = Phi @ x + Gam * uk
    return y


@pytest.mark.parametrize("size", [2, 3, 5])
def test_jordan_block_uses_doubling_and_is_exact(size):
    model = JordanModel(TINY, size=size)
    theta = np.array([2.0e5, 3.0])
    ss = model.state_space(theta)
    assert sim.engine_path(ss, 1e-6, sensitivities=False) == "doubling"
    u = prbs_like(np.random.default_rng(size), 800, 7)
    y = sim.simulate(model, theta, u, 1e-6)
    assert rel(y, _zoh_recursion(ss, u, 1e-6)) < 1e-11
    # Closed form of the impulse-invariant check for m = 2: step response of a^1 g/(s+a)^2.
    if size == 2:
        a, g = theta
        t = np.arange(800) * 1e-6
        step = g / a * (1 - np.exp(-a * t) - a * t * np.exp(-a * t))
        assert rel(sim.simulate(model, theta, np.ones(800), 1e-6), step) < 1e-12
    # Sensitivities of a defective model: exact, compared with central differences.
    _, J = sim.simulate_with_sensitivities(model, theta, u, 1e-6)
    assert col_rel(J, _central_fd(model, theta, u, 1e-6, "zoh")) < 1e-6


@pytest.mark.parametrize("eps", [0.0, 1e-16, 1e-12, 1e-9, 1e-6, 1e-3, 0.3])
@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_near_defective_any_path_is_exact(eps, hold):
    """Whatever path 'auto' picks across the approach to a Jordan block, y and dy/dtheta are exact."""
    model = NearDefectiveModel(TINY)
    theta = np.array([1.5e5, eps])
    u = prbs_like(np.random.default_rng(3), 600, 5)
    y, J = sim.simulate_with_sensitivities(model, theta, u, 1e-6, hold)
    y_d, J_d = sim.simulate_with_sensitivities(model, theta, u, 1e-6, hold, method="doubling")
    assert rel(y, y_d) < 1e-11
    assert rel(sim.simulate(model, theta, u, 1e-6, hold), y_d) < 1e-11
    assert col_rel(J, J_d) < 1e-9


def test_repeated_diagonalisable_eigenvalues():
    model = TwinModel(TINY)
    theta = np.array([2.0 * np.pi * 3e5, 0.02])
    ss = model.state_space(theta)
    assert sim.engine_path(ss, 2e-7, sensitivities=False) == "modal"
    assert sim.engine_path(ss, 2e-7, sensitivities=True) == "doubling"  # lambda_i == lambda_j
    u = prbs_like(np.random.default_rng(4), 2000, 9)
    y, J = sim.simulate_with_sensitivities(model, theta, u, 2e-7)
    assert rel(sim.simulate(model, theta, u, 2e-7), _zoh_recursion(ss, u, 2e-7)) < 1e-10
    assert rel(y, _zoh_recursion(ss, u, 2e-7)) < 1e-10
    assert col_rel(J, _central_fd(model, theta, u, 2e-7, "zoh")) < 1e-6


def test_stiff_chain():
    """Heavy damping: real eigenvalues from ~-1e3 to ~-1e9 1/s (lambda h down to -100)."""
    model = kv(20)
    theta = np.array([3e8, 1e5, 5e7, 1e5])
    ss = model.state_space(theta)
    lam = np.linalg.eigvals(sim.as_float_ss(ss).A)
    assert lam.real.min() * DT < -50
    u = prbs_like(np.random.default_rng(5), 4000)
    for hold in ("zoh", "foh"):
        y_m, J_m = sim.simulate_with_sensitivities(model, theta, u, DT, hold)
        y_d, J_d = sim.simulate_with_sensitivities(model, theta, u, DT, hold, method="doubling")
        assert rel(y_m, y_d) < 1e-11
        assert col_rel(J_m, J_d) < 1e-9
    assert rel(sim.simulate(model, theta, u, DT), _zoh_recursion(ss, u, DT)) < 1e-10


def test_lightly_damped_long_record():
    """Damping ratio ~1e-5 over 120k samples: no drift between the two exact paths."""
    model = kv(10)
    theta = np.array([3e8, 1e-2, 5e7, 1e-2])
    u = prbs_like(np.random.default_rng(6), 120_000, 40)
    y_m = sim.simulate(model, theta, u, DT)
    y_d = sim.simulate(model, theta, u, DT, method="doubling")
    assert rel(y_m, y_d) < 1e-10
    # linear growth check: the last samples still agree sample-by-sample
    assert rel(y_m[-1000:], y_d[-1000:]) < 1e-9


# ---------------------------------------------------------------------------------------
# Sensitivities
# ---------------------------------------------------------------------------------------
def _central_fd(model, theta, u, dt, hold, rel_step=1e-5):
    theta = np.asarray(theta, float)
    cols = []
    for i in range(theta.size):
        h = rel_step * abs(theta[i])
        tp, tm = theta.copy(), theta.copy()
        tp[i] += h
        tm[i] -= h
        cols.append(
            (sim.simulate(model, tp, u, dt, hold, method="doubling") - sim.simulate(model, tm, u, dt, hold, method="doubling"))
            / (2 * h)
        )
    return np.stack(cols, axis=1)


positive = st.floats(min_value=-1.0, max_value=1.0).map(lambda e: 10.0**e)


@given(
    scale=st.tuples(positive, positive, positive, positive),
    n=st.integers(1, 40),
    rate=st.sampled_from([2e6, 6.25e6, 25e6]),
    hold=st.sampled_from(["zoh", "foh"]),
    seed=st.integers(0, 2**31),
)
@settings(max_examples=15)
def test_sensitivities_match_central_differences(scale, n, rate, hold, seed):
    theta = TABLE_3_1 * np.array(scale)
    model = kv(n)
    dt = 1.0 / rate
    u = np.random.default_rng(seed).standard_normal(400)
    _, J = sim.simulate_with_sensitivities(model, theta, u, dt, hold)
    fd = _central_fd(model, theta, u, dt, hold)
    for i in range(4):
        # central difference error ~ (1e-5)^2 curvature + round-off 1e-16/1e-5
        assert rel(J[:, i], fd[:, i]) < 2e-5, (i, rel(J[:, i], fd[:, i]))


def test_complex_step_derivatives_of_model_matrices():
    model = kv(3)
    theta = TABLE_3_1
    derivs = sim.state_space_derivatives(model, theta)
    base = sim.as_float_ss(model.state_space(theta))
    for i, d in enumerate(derivs):
        h = 1e-6 * theta[i]
        tp = theta.copy()
        tp[i] += h
        fd = sim.as_float_ss(model.state_space(tp))
        for M_d, M_p, M_0 in zip(d, fd, base):
            assert np.allclose(M_d, (M_p - M_0) / h, rtol=1e-5, atol=1e-9 * np.abs(M_d).max() + 1e-300)
    # a parameter at exactly zero still gets a finite derivative
    d0 = sim.state_space_derivatives(model, np.array([3e8, 0.0, 5e7, 12.0]))
    assert np.all(np.isfinite(d0[1].A)) and np.abs(d0[1].A).max() > 0


# ---------------------------------------------------------------------------------------
# Linear-system invariances of the sampled output
# ---------------------------------------------------------------------------------------
@given(
    scale=st.tuples(positive, positive, positive, positive),
    n=st.integers(1, 40),
    a=st.floats(-5, 5),
    b=st.floats(-5, 5),
    seed=st.integers(0, 2**31),
    hold=st.sampled_from(["zoh", "foh"]),
)
def test_superposition(scale, n, a, b, seed, hold):
    theta = TABLE_3_1 * np.array(scale)
    model = kv(n)
    rng = np.random.default_rng(seed)
    u1, u2 = rng.standard_normal(500), prbs_like(rng, 500, 11)
    y1 = sim.simulate(model, theta, u1, DT, hold)
    y2 = sim.simulate(model, theta, u2, DT, hold)
    y = sim.simulate(model, theta, a * u1 + b * u2, DT, hold)
    ref = a * y1 + b * y2
    assert np.max(np.abs(y - ref)) <= 1e-12 * (abs(a) * np.abs(y1).max() + abs(b) * np.abs(y2).max()) + 1e-300


@given(
    scale=st.tuples(positive, positive, positive, positive),
    n=st.integers(1, 40),
    shift=st.integers(1, 300),
    seed=st.integers(0, 2**31),
    hold=st.sampled_from(["zoh", "foh"]),
)
def test_time_invariance(scale, n, shift, seed, hold):
    """Delaying the input by s samples delays the output by s samples (zeros before).

    For FOH the continuous input ramps up from u[0] = 0 in both records, so the records
    describe the same continuous signal shifted; the engine's from-rest start term
    (-u[0] C Phi^k Gamma1) must vanish here."""
    theta = TABLE_3_1 * np.array(scale)
    model = kv(n)
    u = np.random.default_rng(seed).standard_normal(600)
    if hold == "foh":
        u[0] = 0.0
    y = sim.simulate(model, theta, u, DT, hold)
    y_s = sim.simulate(model, theta, np.concatenate([np.zeros(shift), u])[:600], DT, hold)
    scale_y = np.abs(y).max()
    assert np.max(np.abs(y_s[:shift])) <= 1e-13 * scale_y
    assert np.max(np.abs(y_s[shift:] - y[: 600 - shift])) <= 1e-11 * scale_y


def test_foh_start_term():
    """FOH from rest with u[0] != 0: the start term is what separates the old effective-form
    result from the true response. A constant input u = 1 under FOH is a unit step at t = 0+,
    the same continuous input as ZOH of u = 1, so both holds must agree exactly."""
    model = kv(10)
    u = np.ones(2000)
    y_foh = sim.simulate(model, TABLE_3_1, u, DT, "foh")
    y_zoh = sim.simulate(model, TABLE_3_1, u, DT, "zoh")
    assert rel(y_foh, y_zoh) < 1e-11
    for method in ("modal", "doubling"):
        assert rel(sim.simulate(model, TABLE_3_1, u, DT, "foh", method=method), y_zoh) < 1e-11


# ---------------------------------------------------------------------------------------
# Batches, caching, edge cases, argument checking
# ---------------------------------------------------------------------------------------
def test_batches_equal_single_calls():
    model = kv(6)
    rng = np.random.default_rng(7)
    thetas = TABLE_3_1 * 10 ** rng.uniform(-0.5, 0.5, (5, 4))
    thetas[2] = [2e5, 1.0, 3e5, 2.0]  # whatever path
    u = prbs_like(rng, 1500)
    for hold in ("zoh", "foh"):
        Y = sim.simulate_batch(model, thetas, u, DT, hold)
        Yb, Jb = sim.simulate_with_sensitivities_batch(model, thetas, u, DT, hold)
        for b, th in enumerate(thetas):
            y, J = sim.simulate_with_sensitivities(model, th, u, DT, hold)
            assert rel(Y[b], sim.simulate(model, th, u, DT, hold)) < 1e-13
            assert rel(Yb[b], y) < 1e-13
            assert col_rel(Jb[b], J) < 1e-13
            # y alone and y with sensitivities may take different exact paths
            assert rel(Y[b], y) < 1e-10


def test_input_spectrum_cache_sees_in_place_changes():
    model = kv(4)
    u = prbs_like(np.random.default_rng(8), 1000)
    y1 = sim.simulate(model, TABLE_3_1, u, DT)
    u *= 2.0  # same array object, new values
    y2 = sim.simulate(model, TABLE_3_1, u, DT)
    assert rel(y2, 2 * y1) < 1e-13


@pytest.mark.parametrize("N", [0, 1, 2, 3])
def test_short_records(N):
    model = NearDefectiveModel(TINY)
    theta = np.array([1e5, 0.2])
    u = np.arange(1, N + 1, dtype=float)
    for hold in ("zoh", "foh"):
        y, J = sim.simulate_with_sensitivities(model, theta, u, 1e-6, hold)
        assert y.shape == (N,) and J.shape == (N, 2)
        y_d, J_d = sim.simulate_with_sensitivities(model, theta, u, 1e-6, hold, method="doubling")
        if N:
            assert rel(y, y_d) < 1e-12 and col_rel(J, J_d) < 1e-10
        if N:
            assert y[0] == pytest.approx(0.1 * u[0], rel=1e-14)  # y[0] = D u[0] from rest


def test_bad_arguments():
    model = kv(2)
    with pytest.raises(ValueError, match="hold"):
        sim.simulate(model, TABLE_3_1, np.ones(10), DT, "cubic")
    with pytest.raises(ValueError, match="method"):
        sim.simulate(model, TABLE_3_1, np.ones(10), DT, method="fast")


def test_record_ending_before_the_wave_arrives_falls_back():
    """A 4 us record through a slow 20-element chain: the output is the t^(2n-1) foot of the
    response, ~1e-20 of the modal terms, so the modal sums would be round-off. The
    amplification check must send it to the doubling path, whose result 'auto' returns."""
    model = kv(20)
    theta = np.array([3e7, 15.0, 5e6, 12.0])
    u = prbs_like(np.random.default_rng(9), 100, 3)
    dt = 4e-8
    ss = model.state_space(theta)
    derivs = sim.state_space_derivatives(model, theta)
    assert sim.engine_path(ss, dt) == "modal"  # a-priori checks alone would accept it
    assert sim.engine_path(ss, dt, u=u) == "doubling"
    assert sim.engine_path(ss, dt, True, u, derivatives=derivs) == "doubling"
    y = sim.simulate(model, theta, u, dt)
    assert np.array_equal(y, sim.simulate(model, theta, u, dt, method="doubling"))
    # and the Table 3.1 record itself stays on the fast path
    full = kv(10)
    w = prbs_like(np.random.default_rng(10), 6200)
    ss31 = full.state_space(TABLE_3_1)
    assert sim.engine_path(ss31, DT, False, w) == "modal"
    assert sim.engine_path(ss31, DT, True, w, derivatives=sim.state_space_derivatives(full, TABLE_3_1)) == "modal"
