"""Contract test suite for medium-model plugins (pytest mixin, scipy style).

A model author subclasses :class:`MediumModelContract` in a test module and says which
models to check::

    from mbus_framework.interfaces.sample import Sample
    from mbus_framework.testing.models import MediumModelContract

    class TestMyChain(MediumModelContract):
        model_name = "my_chain"                       # registered name (checked)

        def make_models(self):
            s = Sample(length=0.02, diameter=0.0254, density=1000.0)
            return [MyChain(s, MyChain.Options(n_elements=3))]

and runs ``pytest``. Every test runs over every model of :meth:`make_models` and over random
positive parameters theta = typical * exp(U(-ln spread, ln spread)) (hypothesis draws):

* declarations: unique names, units, bounds around ``typical``, finite time exponents,
  ``Options`` rejecting unknown keys;
* dimensions: A (n x n), B (n x 1), C (1 x n), D (1 x 1), finite;
* stability: every pole has a negative real part;
* passivity (no energy created): the driving-point admittance Y = v_1/u is positive real,
  Re Y(j w) >= 0, and the exact work delivered by the source from rest,
  W(t) = int u v_1 dt, never goes negative (needs ``model.driving_point_output(theta)``,
  the row C_v with v_1 = C_v z, as the chain models provide; otherwise skipped);
* property conversion invertible: from_properties(to_properties(theta)) = theta;
* arithmetic only: complex-step derivatives equal central differences, and the CasADi
  symbolic evaluation equals the numeric one;
* time exponents: scaling theta_i by c**e_i makes the dynamics exactly c times faster,
  H(j c w; theta_c) = H(j w; theta) (skipped for a model whose ``exact_time_scaling`` is
  False, e.g. a layered sample with coefficients fixed by the config);
* initial guess: finite, positive and within bounds on a simulated record;
* solvers: every registered solver fits a short noise-free record from a start 5 % off.
"""
from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mbus_framework.engine.arrays import to_casadi
from mbus_framework.interfaces.model import MediumModel, StateSpace
from mbus_framework.engine.simulation import as_float_ss, simulate, simulate_ss
from mbus_framework.estimation.problem import FitProblem

# differing_executors: the tests are shared by every subclass (one per model), by design.
_SETTINGS = settings(max_examples=10, deadline=None,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.differing_executors])


def _rel_err(a, b) -> float:
    a = np.asarray(a, dtype=complex)
    b = np.asarray(b, dtype=complex)
    scale = max(np.max(np.abs(a), initial=0.0), np.max(np.abs(b), initial=0.0), 1e-300)
    return float(np.max(np.abs(a - b), initial=0.0) / scale)


def typical_theta(model: MediumModel) -> np.ndarray:
    return np.array([p.typical for p in model.parameters], dtype=float)


def response(ss: StateSpace, s: np.ndarray, C: np.ndarray | None = None) -> np.ndarray:
    """C (sI - A)^-1 B + D at complex frequencies ``s`` (continuous time)."""
    A, B, Cm, D = as_float_ss(ss)
    C = Cm if C is None else np.atleast_2d(C)
    n = A.shape[0]
    M = s[:, None, None] * np.eye(n)[None] - A[None]
    x = np.linalg.solve(M, np.broadcast_to(B.astype(complex), (s.size, n, 1)))[..., 0]
    d = D[0, 0] if C is Cm else 0.0
    return x @ C[0].astype(complex) + d


def sampling_interval(model: MediumModel, theta) -> float:
    """dt with |lambda|_max dt = 0.15 (about the dissertation's sampling of its chains)."""
    lam = np.linalg.eigvals(as_float_ss(model.state_space(np.asarray(theta, float))).A)
    return 0.15 / float(np.max(np.abs(lam)))


def binary_input(n: int, bit: int = 3, seed: int = 0) -> np.ndarray:
    """Random +-1 sequence with bits ``bit`` samples long (a PRBS stand-in)."""
    rng = np.random.default_rng(seed)
    return np.repeat(rng.choice([-1.0, 1.0], n // bit + 1), bit)[:n]


class MediumModelContract:
    """Mixin of contract tests for :class:`~mbus_framework.interfaces.model.MediumModel` plugins.

    Override :meth:`make_models`; optionally ``model_name`` (checked to be registered),
    ``spread`` (random parameters within typical x/÷ spread), ``registry`` (default: the
    process-wide one), ``solver_names`` (default: every registered solver),
    ``solver_options`` (per solver, kept fast by default) and ``solver_record_samples``.
    """

    model_name: ClassVar[str | None] = None
    spread: ClassVar[float] = 10.0
    registry: ClassVar[Any] = None
    solver_names: ClassVar[list[str] | None] = None
    solver_options: ClassVar[dict[str, dict]] = {
        "scipy_lm": {"strategy": {"n_starts": 1, "bands": [], "time_scale": False}},
    }
    solver_record_samples: ClassVar[int] = 400
    passivity_rtol: ClassVar[float] = 1e-9

    # -- what to test -----------------------------------------------------------------------
    def make_models(self) -> list[MediumModel]:
        raise NotImplementedError("subclasses of MediumModelContract return their model instances here")

    def get_registry(self):
        if self.registry is not None:
            return self.registry
        from mbus_framework.interfaces.registry import default_registry

        return default_registry()

    def draw_theta(self, data, model: MediumModel) -> np.ndarray:
        """typical * exp(uniform in [-ln spread, ln spread]) per parameter (hypothesis draw)."""
        r = float(np.log(self.spread))
        logs = data.draw(st.lists(st.floats(-r, r), min_size=len(model.parameters),
                                  max_size=len(model.parameters)), label=f"log multipliers {type(model).__name__}")
        return typical_theta(model) * np.exp(np.array(logs))

    # -- declarations -----------------------------------------------------------------------
    def test_declarations(self):
        for model in self.make_models():
            names = model.parameter_names
            assert len(names) >= 1 and len(set(names)) == len(names), f"parameter names not unique: {names}"
            pnames = model.property_names
            assert len(set(pnames)) == len(pnames), f"property names not unique: {pnames}"
            for p in model.parameters:
                assert p.unit is not None and p.description, f"{p.name}: give a unit and a description"
                assert np.isfinite(p.time_exponent), f"{p.name}: time_exponent must be finite"
                assert p.lower < p.typical < p.upper, f"{p.name}: typical {p.typical} outside ({p.lower}, {p.upper})"
                assert p.lower >= 0.0, f"{p.name}: the contract covers positive parameters"
            assert type(model).summary, "set the class attribute `summary`"
            cfg = getattr(type(model).Options, "model_config", {})
            assert cfg.get("extra") == "forbid", "Options must reject unknown keys (extra='forbid')"

    def test_registered(self):
        if self.model_name is None:
            pytest.skip("model_name not set")
        spec = self.get_registry().get("model", self.model_name)
        kinds = {type(m) for m in self.make_models()}
        assert spec.implementation in kinds, f"'{self.model_name}' is registered as {spec.implementation}"

    # -- structure ---------------------------------------------------------------------------
    def test_dimensions(self):
        for model in self.make_models():
            theta = typical_theta(model)
            A, B, C, D = (np.asarray(m) for m in model.state_space(theta))
            n = A.shape[0]
            assert A.shape == (n, n) and B.shape == (n, 1) and C.shape == (1, n) and D.shape == (1, 1), (
                f"shapes A{A.shape} B{B.shape} C{C.shape} D{D.shape}")
            for m in (A, B, C, D):
                assert np.all(np.isfinite(m.astype(float)))
            assert model.n_states == n
            assert np.any(B != 0) and np.any(C != 0), "input or output not connected"

    @_SETTINGS
    @given(data=st.data())
    def test_poles_stable(self, data):
        for model in self.make_models():
            theta = self.draw_theta(data, model)
            lam = np.linalg.eigvals(as_float_ss(model.state_space(theta)).A)
            assert np.max(lam.real) < 0.0, (
                f"{type(model).__name__} unstable at theta={theta.tolist()}: max Re(pole) = {np.max(lam.real):.3g}")

    @_SETTINGS
    @given(data=st.data())
    def test_passive(self, data):
        checked = False
        for model in self.make_models():
            if not hasattr(model, "driving_point_output"):
                continue
            checked = True
            theta = self.draw_theta(data, model)
            ss = as_float_ss(model.state_space(theta))
            Cv = np.atleast_2d(np.asarray(model.driving_point_output(theta), dtype=float))
            lam = np.linalg.eigvals(ss.A)
            w = np.concatenate([np.logspace(np.log10(np.min(np.abs(lam))) - 3, np.log10(np.max(np.abs(lam))) + 3, 400),
                                np.abs(lam.imag[lam.imag > 0])])
            Y = response(ss, 1j * w, Cv)
            assert np.min(Y.real) >= -self.passivity_rtol * np.max(np.abs(Y)), (
                f"{type(model).__name__}: admittance not positive real (min Re Y = {np.min(Y.real):.3g}) "
                f"at theta={theta.tolist()}")
            # Exact work of the source from rest: W_K = sum_k u_k (p_{k+1} - p_k), p = int v_1.
            n = ss.A.shape[0]
            A_aug = np.zeros((n + 1, n + 1))
            A_aug[:n, :n] = ss.A
            A_aug[n, :n] = Cv[0]
            B_aug = np.vstack([ss.B, [[0.0]]])
            C_aug = np.zeros((1, n + 1))
            C_aug[0, n] = 1.0
            dt = sampling_interval(model, theta)
            u = binary_input(600, 3, seed=int(data.draw(st.integers(0, 2**16), label="input seed")))
            p = simulate_ss(StateSpace(A_aug, B_aug, C_aug, np.zeros((1, 1))), np.append(u, 0.0), dt)
            work = np.cumsum(u * np.diff(p))
            assert np.min(work) >= -self.passivity_rtol * np.max(np.abs(work)), (
                f"{type(model).__name__}: the source extracted energy (W = {np.min(work):.3g} J)")
        if not checked:
            pytest.skip("no model exposes driving_point_output(theta); passivity not checked")

    # -- properties --------------------------------------------------------------------------
    @_SETTINGS
    @given(data=st.data())
    def test_property_roundtrip(self, data):
        for model in self.make_models():
            theta = self.draw_theta(data, model)
            props = model.to_properties(theta)
            assert list(props) == model.property_names, "to_properties keys must follow `properties`"
            back = np.asarray(model.from_properties(props), dtype=float)
            np.testing.assert_allclose(back, theta, rtol=1e-12, err_msg="from_properties(to_properties(theta))")
            again = model.to_properties(back)
            np.testing.assert_allclose([again[k] for k in props], [props[k] for k in props], rtol=1e-12)
            via_mapping = model.theta_from_mapping(props, "properties")
            np.testing.assert_allclose(via_mapping, theta, rtol=1e-12)

    # -- arithmetic only -------------------------------------------------------------------
    def test_complex_step_matches_finite_difference(self):
        for model in self.make_models():
            theta = typical_theta(model) * np.exp(np.linspace(-0.3, 0.3, len(model.parameters)))
            base = as_float_ss(model.state_space(theta))
            for i, p in enumerate(model.parameters):
                h = 1e-20 * theta[i]
                tc = theta.astype(complex)
                tc[i] += 1j * h
                cs = [np.atleast_2d(np.asarray(m, dtype=complex)) for m in model.state_space(tc)]
                for real, m in zip(cs, base):
                    assert _rel_err(real.real, m) < 1e-14, f"complex evaluation changes values ({p.name})"
                d = 1e-6 * theta[i]
                up, dn = theta.copy(), theta.copy()
                up[i] += d
                dn[i] -= d
                fd = [(a - b) / (2 * d) for a, b in zip(as_float_ss(model.state_space(up)), as_float_ss(model.state_space(dn)))]
                for name, c_, f_ in zip("ABCD", cs, fd):
                    err = _rel_err(c_.imag / h, f_)
                    scale = np.max(np.abs(f_), initial=0.0)
                    assert err < 1e-5 or scale == 0.0, (
                        f"d{name}/d{p.name}: complex step and finite difference disagree ({err:.2g}); "
                        "is state_space arithmetic only (no abs, comparisons, np.linalg)?")

    def test_casadi_matches_numeric(self):
        ca = pytest.importorskip("casadi")
        for model in self.make_models():
            p = len(model.parameters)
            sym = ca.SX.sym("theta", p)
            th_obj = np.array([sym[i] for i in range(p)], dtype=object)
            ss_sym = model.state_space(th_obj)
            f = ca.Function("ss", [sym], [to_casadi(m) for m in ss_sym])
            theta = typical_theta(model) * np.exp(np.linspace(-0.5, 0.5, p))
            for out, num in zip(f(theta), as_float_ss(model.state_space(theta))):
                assert _rel_err(np.array(out), num) < 1e-12

    # -- time scaling ------------------------------------------------------------------------
    @_SETTINGS
    @given(data=st.data(), log_c=st.floats(-2.0, 2.0))
    def test_time_exponents(self, data, log_c):
        c = float(np.exp(log_c))
        for model in self.make_models():
            if not getattr(model, "exact_time_scaling", True):
                continue  # e.g. coefficients fixed by the config do not scale
            theta = self.draw_theta(data, model)
            e = np.array([p.time_exponent for p in model.parameters])
            ss = as_float_ss(model.state_space(theta))
            ss_c = as_float_ss(model.state_space(theta * c**e))
            lam = np.linalg.eigvals(ss.A)
            w = np.logspace(np.log10(np.min(np.abs(lam))) - 1, np.log10(np.max(np.abs(lam))) + 1, 60)
            H = response(ss, 1j * w)
            Hc = response(ss_c, 1j * c * w)
            assert _rel_err(Hc, H) < 1e-7, (
                f"{type(model).__name__}: scaling theta by c**time_exponent (c={c:.3g}) does not speed the "
                f"dynamics up by c; check every Parameter.time_exponent")

    # -- initial values ----------------------------------------------------------------------
    def test_initial_guess(self):
        for model in self.make_models():
            truth = typical_theta(model)
            dt = sampling_interval(model, truth)
            u = binary_input(1500, 4)
            t = np.arange(u.size) * dt
            y = simulate(model, truth, u, dt)
            guess = np.asarray(model.initial_guess(t, u, y), dtype=float)
            lo, hi = model.bounds()
            assert guess.shape == truth.shape
            assert np.all(np.isfinite(guess)) and np.all(guess > 0), guess
            assert np.all(guess >= lo) and np.all(guess <= hi)

    # -- solvers -----------------------------------------------------------------------------
    def test_every_solver_fits_short_record(self):
        registry = self.get_registry()
        names = self.solver_names if self.solver_names is not None else registry.names("solver")
        if not names:
            pytest.skip("no solver registered")
        from mbus_framework.pipeline.config import validate_options

        model = self.make_models()[0]
        truth = typical_theta(model)
        dt = sampling_interval(model, truth)
        start = truth * 1.05
        for name in names:
            spec = registry.get("solver", name)
            n = self.solver_record_samples
            u = binary_input(n, 4, seed=1)
            if getattr(spec.implementation, "periodic_records", False):  # four periods of the whole input
                u = np.tile(u, 4)
            t = np.arange(u.size) * dt
            y = simulate(model, truth, u, dt)
            options = validate_options(spec.implementation.Options, self.solver_options.get(name, {}),
                                       f"solver_options[{name}]")
            solver = spec.implementation(options)
            problem = FitProblem(model, t, u, y, initial=start.copy())
            fit = solver.solve(problem)
            yhat = simulate(model, fit.theta, u, dt)
            rel = float(np.linalg.norm(y - yhat) / np.linalg.norm(y))
            rel0 = float(np.linalg.norm(y - simulate(model, start, u, dt)) / np.linalg.norm(y))
            assert rel < 1e-3 and rel < 0.1 * rel0, (
                f"solver '{name}' on {type(model).__name__}: relative output error {rel:.3g} "
                f"(start {rel0:.3g}); message: {fit.message}")
            assert list(fit.names) == model.parameter_names
