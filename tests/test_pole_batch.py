"""The record-pole phase's batched evaluation (issue 24) against the unbatched reference:
:meth:`ChainModel.state_matrices_batch` equals ``state_space(theta).A`` row by row exactly
(every chain model and link law, non-finite rows, laws that do not broadcast), and a pole
refinement with its residual and Jacobian points evaluated in one batch follows the same
path as one evaluating every point on its own."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from mbus_framework.engine.chain import KelvinVoigtLaw
from mbus_framework.estimation import global_search as gs
from mbus_framework.estimation import poles
from mbus_framework.interfaces.sample import Sample
from mbus_framework.estimation.poles import POLE_CAP, DIFF_STEP, _forward_steps, record_poles
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from tests.test_compiled_assembly import MODELS, _theta
from tests.test_global_minimum import record
from tests.test_record_poles import ringing_chain


def _rows(model, thetas):
    return np.array([np.asarray(model.state_space(th).A, float) for th in thetas])


@pytest.mark.parametrize("model", MODELS, ids=lambda m: f"{type(m).__name__}")
def test_batched_state_matrices_equal_state_space_row_by_row(model):
    thetas = np.array([_theta(model, seed) for seed in range(40)])
    np.testing.assert_array_equal(model.state_matrices_batch(thetas), _rows(model, thetas))
    one = thetas[:1]
    np.testing.assert_array_equal(model.state_matrices_batch(one), _rows(model, one))


def test_batched_state_matrices_with_non_finite_rows_take_the_row_path():
    model = MODELS[0]
    thetas = np.array([_theta(model, seed) for seed in range(5)])
    thetas[1, 0], thetas[3, 1] = np.inf, np.nan
    with np.errstate(all="ignore"):
        got, ref = model.state_matrices_batch(thetas), _rows(model, thetas)
    np.testing.assert_array_equal(got, ref)  # nan == nan here: same positions, same values
    assert np.all(np.isfinite(got[[0, 2, 4]])) and not np.all(np.isfinite(got[1]))


class _ScalarOnlyLaw(KelvinVoigtLaw):
    """Kelvin-Voigt written with float(): does not broadcast over parameter columns."""

    def matrices(self, p):
        return super().matrices([float(v) for v in p])


class _ScalarOnlyChain(KelvinVoigtChain):
    normal = _ScalarOnlyLaw()
    shear = _ScalarOnlyLaw()


def test_batched_state_matrices_fall_back_for_laws_that_do_not_broadcast():
    model = _ScalarOnlyChain(Sample(0.03, 0.0254, 1080.0), KelvinVoigtOptions(n_elements=5))
    plain = KelvinVoigtChain(Sample(0.03, 0.0254, 1080.0), KelvinVoigtOptions(n_elements=5))
    thetas = np.array([_theta(model, seed) for seed in range(6)])
    with pytest.raises(TypeError):
        model._link_matrices(list(thetas.T))  # the batch path is not open to this law
    np.testing.assert_array_equal(model.state_matrices_batch(thetas), _rows(model, thetas))
    np.testing.assert_array_equal(model.state_matrices_batch(thetas), plain.state_matrices_batch(thetas))


def _reference_refinement(problem, space, z, theta, max_nfev=200):
    """The refinement with every point's poles from its own ``state_space`` and eigenvalue
    call (no batch, no early stop)."""
    mv = np.flatnonzero(space.movable)
    h, n_model = problem.dt, problem.n_model
    theta = np.clip(np.asarray(theta, float), space.lo, space.hi)
    zlo, zhi = np.log(space.lo[mv]), np.log(space.hi[mv])

    def theta_of(x):
        th = theta.copy()
        th[mv] = np.exp(np.clip(x, zlo, zhi))
        return th

    def residual(x):
        s = poles._continuous_poles(problem.model, theta_of(x)[:n_model])
        if s.size == 0:
            return np.full(z.size, POLE_CAP)
        return np.minimum(np.abs(z[:, None] - np.exp(s * h)[None, :]).min(axis=1), POLE_CAP)

    def jacobian(x):
        f0 = residual(x)
        xs, dx = _forward_steps(x, DIFF_STEP)
        return np.array([(residual(xi) - f0) / d for xi, d in zip(xs, dx)]).T

    e = space.e[mv]
    soft = e != e.max()
    x0 = np.log(theta[mv])
    xs = np.repeat(x0[None, :], 41, axis=0)
    xs[:, soft] = zlo[soft] + np.linspace(0.0, 1.0, 41)[:, None] * (zhi[soft] - zlo[soft])
    x0 = xs[int(np.argmin([float(np.sum(residual(x) ** 2)) for x in xs]))]
    res = least_squares(residual, x0, jac=jacobian, method="trf", max_nfev=max_nfev, x_scale=1.0)
    return theta_of(res.x), float(2 * res.cost)


def test_batched_refinement_follows_the_unbatched_path_exactly():
    model, theta = ringing_chain(3e11, 50.0, 2e11, 30.0, L=0.02, n=6)
    problem, _ = record(model, theta, 10, 2.5e-6, 6.25e6, 6200, 0.05, seed=2, state=9)
    space = gs.search_space(problem)
    template = np.array([p.typical for p in problem.parameters])
    z = record_poles(problem.u, problem.y, problem.model.n_states)
    patterns = poles.pattern_search(problem, space, z, template, keep=3)
    assert patterns
    for p in patterns:
        got = poles.refine_on_poles(problem, space, z, p.theta)
        ref_theta, ref_cost = _reference_refinement(problem, space, z, p.theta)
        assert got.cost == ref_cost
        np.testing.assert_array_equal(got.theta, ref_theta)
