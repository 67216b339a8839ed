"""Contract test suite for solver plugins (pytest mixin, scipy style).

A solver author subclasses :class:`SolverContract` in a test module and names the solver::

    from mbus_framework.testing.solvers import SolverContract

    class TestMySolver(SolverContract):
        solver_name = "my_solver"                  # registered name (checked)
        solver_options = {"tolerance": 1e-10}      # validated against MySolver.Options

and runs ``pytest``; :func:`contract_classes` makes one such class per registered solver
(``tests/test_solver_contract.py`` runs it over every solver we ship). The checks use a short
noise-free record of a Kelvin-Voigt chain (n = 3, 2 cm, Table 3.1-like properties, a random
binary input sampled with |lambda|_max h = 0.12); override :meth:`make_problem` for another.

* registration: the name is registered, ``Options`` rejects unknown keys;
* truth recovery: from a start 15-25 % off, the estimate matches the truth to ``truth_rtol``;
* bounds: with an upper bound below the truth (k_sigma) and a lower bound above it (b_tau),
  the estimate stays inside the bounds and k_sigma ends on its bound;
* fixed parameters keep their value and drop out of ``free`` and the Jacobian;
* common fields: names, theta, success/status/message, counts, cost = 1/2 ||residuals||^2 with
  residuals = y - yhat(theta), the Jacobian d yhat/d theta (free columns), trace records,
  strategy and extras as JSON-serialisable mappings, a positive wall time.
"""
from __future__ import annotations

import json
from typing import Any, ClassVar

import numpy as np

from mbus_framework.interfaces.sample import Sample
from mbus_framework.engine.simulation import as_float_ss, simulate
from mbus_framework.estimation.problem import FitProblem, FitResult

#: Table 3.1-like material: E_sigma [Pa], eta_sigma [Pa s], E_tau [Pa], eta_tau [Pa s]
CONTRACT_PROPERTIES = {"E_sigma": 2.5e9, "eta_sigma": 150.0, "E_tau": 6.0e8, "eta_tau": 150.0}
START_FACTORS = np.array([1.2, 0.8, 1.25, 0.85])


def binary_record(n: int, bit: int, seed: int, period: int | None = None) -> np.ndarray:
    """Random +-1 sequence with bits ``bit`` samples long (a PRBS stand-in); with ``period``,
    its first ``period`` samples repeated (for solvers that need a periodic record)."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.choice([-1.0, 1.0], n // bit + 1), bit)[:n]
    return u if period is None else np.tile(u[:period], n // period + 1)[:n]


def contract_problem(n_samples: int = 600, n_elements: int = 3, seed: int = 4, registry=None,
                     periodic: bool = False, **kw) -> tuple[FitProblem, np.ndarray]:
    """(noise-free problem, truth) of the registered ``kelvin_voigt`` chain; ``periodic``: the
    input repeats every n_samples/4 samples; ``kw`` go to :class:`FitProblem` (initial,
    fixed, lower, upper, ...)."""
    if registry is None:
        from mbus_framework.interfaces.registry import default_registry

        registry = default_registry()
    cls = registry.get("model", "kelvin_voigt").implementation
    model = cls(Sample(0.02, 0.0254, 1000.0), cls.Options(n_elements=n_elements))
    truth = model.from_properties(CONTRACT_PROPERTIES)
    lam = np.linalg.eigvals(as_float_ss(model.state_space(truth)).A)
    dt = 0.12 / float(np.max(np.abs(lam)))
    u = binary_record(n_samples, 8, seed, n_samples // 4 if periodic else None)
    t = np.arange(n_samples) * dt
    y = simulate(model, truth, u, dt)
    return FitProblem(model, t, u, y, **kw), truth


class SolverContract:
    """Mixin of contract tests for :class:`~mbus_framework.estimation.problem.Solver` plugins.

    Set ``solver_name``; optionally ``solver_options`` (a mapping validated by the solver's
    ``Options``), ``registry`` (default: the process-wide one) and the tolerances.
    """

    solver_name: ClassVar[str | None] = None
    solver_options: ClassVar[dict[str, Any]] = {}
    registry: ClassVar[Any] = None
    truth_rtol: ClassVar[float] = 1e-6
    bound_rtol: ClassVar[float] = 1e-9

    # -- helpers ----------------------------------------------------------------------------
    def get_registry(self):
        if self.registry is not None:
            return self.registry
        from mbus_framework.interfaces.registry import default_registry

        return default_registry()

    def make_solver(self):
        from mbus_framework.pipeline.config import validate_options

        spec = self.get_registry().get("solver", self.solver_name)
        options = validate_options(spec.implementation.Options, dict(self.solver_options),
                                   f"solver_options[{self.solver_name}]")
        return spec.implementation(options)

    def make_problem(self, **kw) -> tuple[FitProblem, np.ndarray]:
        """(noise-free problem, truth); ``kw`` (initial, fixed, lower, upper) go to FitProblem."""
        spec = self.get_registry().get("solver", self.solver_name)
        periodic = bool(getattr(spec.implementation, "periodic_records", False))
        if periodic:  # 4 periods of 300 samples: enough lines for the transient projection
            kw.setdefault("n_samples", 1200)
        return contract_problem(registry=self.get_registry(), periodic=periodic, **kw)

    def _fit(self, **kw) -> tuple[FitProblem, np.ndarray, FitResult]:
        problem, truth = self.make_problem(**kw)
        if problem.initial is None:
            problem.initial = truth * START_FACTORS
        return problem, truth, self.make_solver().solve(problem)

    # -- registration ---------------------------------------------------------------------------
    def test_registered_with_strict_options(self):
        import pytest
        from pydantic import ValidationError

        assert self.solver_name, "set solver_name"
        spec = self.get_registry().get("solver", self.solver_name)
        assert spec.summary, "register the solver with a one-line summary"
        with pytest.raises(ValidationError):
            spec.implementation.Options.model_validate({"no_such_option_xyz": 1})

    # -- behaviour ------------------------------------------------------------------------------
    def test_recovers_truth_on_noise_free_data(self):
        problem, truth, fit = self._fit()
        err = np.abs(fit.theta / truth - 1.0)
        assert np.all(err < self.truth_rtol), (
            f"solver '{self.solver_name}': relative errors {err} (tolerance {self.truth_rtol}); {fit.message}")
        assert fit.success, f"solver '{self.solver_name}' reports failure: {fit.message}"

    def test_respects_bounds(self):
        problem, truth = self.make_problem()
        lower, upper = problem.lower.copy(), problem.upper.copy()
        upper[0] = 0.9 * truth[0]  # k_sigma may not reach its true value
        lower[3] = 1.2 * truth[3]  # nor may b_tau
        problem, truth, fit = self._fit(lower=lower, upper=upper)
        tol = self.bound_rtol * np.abs(np.where(np.isfinite(upper), upper, lower))
        assert np.all(fit.theta >= lower - tol) and np.all(fit.theta <= upper + tol), (
            f"solver '{self.solver_name}' left the bounds: {fit.theta} not in [{lower}, {upper}]")
        # the data pull k_sigma towards its truth, so its bound is active
        np.testing.assert_allclose(fit.theta[0], upper[0], rtol=1e-3)

    def test_keeps_fixed_parameters(self):
        problem, truth = self.make_problem()
        name = problem.names[3]
        problem, truth, fit = self._fit(fixed={name: float(truth[3])})
        assert fit.theta[3] == truth[3], f"fixed {name} moved to {fit.theta[3]}"
        assert fit.free is not None and not fit.free[3] and fit.free[:3].all()
        assert fit.jacobian is not None and fit.jacobian.shape == (problem.y.size, 3)
        np.testing.assert_allclose(fit.theta[:3], truth[:3], rtol=max(self.truth_rtol, 1e-6))

    def test_reports_common_fields(self):
        problem, truth, fit = self._fit()
        N, p = problem.y.size, len(problem.names)
        assert isinstance(fit, FitResult)
        assert list(fit.names) == problem.names
        assert np.shape(fit.theta) == (p,) and np.all(np.isfinite(fit.theta))
        assert isinstance(fit.success, (bool, np.bool_)) and isinstance(fit.status, (int, np.integer))
        assert bool(fit.success) == (fit.status > 0), "success must mean status > 0 (scipy convention)"
        assert isinstance(fit.message, str) and fit.message
        for count in (fit.nfev, fit.njev, fit.iterations):
            assert isinstance(count, (int, np.integer)) and count >= 0
        assert fit.nfev >= 1
        assert fit.wall_time_s > 0
        # residuals and cost describe the returned estimate on the problem's own prediction
        assert np.shape(fit.residuals) == (N,)
        np.testing.assert_allclose(fit.residuals, problem.y - problem.predict(fit.theta),
                                   atol=1e-12 * np.max(np.abs(problem.y)))
        np.testing.assert_allclose(fit.cost, 0.5 * float(fit.residuals @ fit.residuals), rtol=1e-12, atol=1e-300)
        # Jacobian: d yhat / d theta at the estimate, free columns
        assert fit.free is not None and fit.free.dtype == bool and fit.free.shape == (p,)
        _, J = problem.predict_with_jacobian(fit.theta)
        assert fit.jacobian is not None
        np.testing.assert_allclose(fit.jacobian, J[:, fit.free], rtol=1e-6, atol=1e-9 * np.max(np.abs(J)))
        # trace, strategy and extras are plain data (they go into result.json)
        assert isinstance(fit.trace, list)
        for rec in fit.trace:
            assert {"iteration", "cost", "theta"} <= set(rec) and len(rec["theta"]) == p
        assert isinstance(fit.strategy, dict) and isinstance(fit.extras, dict)
        from mbus_framework.pipeline.storage import to_jsonable

        json.dumps(to_jsonable({"strategy": fit.strategy, "extras": fit.extras, "trace": fit.trace}))


def contract_classes(options: dict[str, dict[str, Any]] | None = None, registry=None) -> dict[str, type]:
    """One :class:`SolverContract` subclass per registered solver, keyed by class name.

    ``options`` maps solver names to their ``solver_options``. In a test module::

        globals().update(contract_classes({"scipy_lm": {...}}))
    """
    if registry is None:
        from mbus_framework.interfaces.registry import default_registry

        registry = default_registry()
    options = options or {}
    out = {}
    for name in registry.names("solver"):
        cls_name = "TestSolverContract_" + "".join(c if c.isalnum() else "_" for c in name)
        out[cls_name] = type(cls_name, (SolverContract,), {
            "solver_name": name, "solver_options": options.get(name, {}), "registry": registry})
    return out
