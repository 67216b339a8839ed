"""Batched frequency responses (issue 24): one call for many parameter vectors equals the
single evaluation, over the whole search box (where modal sums cancel and the batch solves
directly); the DTFT of several records equals the direct sum."""
import numpy as np
import pytest

from mbus_framework.engine.frequency import PEAK_TOLERANCE, _direct_response, response, response_batch
from mbus_framework.engine.simulation import as_float_ss
from mbus_framework.interfaces.sample import Sample
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions


def _chain(n=10):
    return KelvinVoigtChain(Sample(0.05, 0.0254, 1000.0), KelvinVoigtOptions(n_elements=n))


def _thetas(count, seed=0):
    rng = np.random.default_rng(seed)
    base = np.array([3e8, 15.0, 5e7, 12.0])
    return base * np.exp(rng.uniform(-1.5, 1.5, size=(count, 4)))


@pytest.mark.parametrize("dt", [None, 1 / 6.25e6])
def test_batch_equals_single_evaluation(dt):
    model = _chain()
    thetas = _thetas(9)
    f = np.geomspace(2e3, 1.5e6, 80)
    batch = response_batch(model, thetas, f, dt)
    assert batch.shape == (9, 80)
    for k, th in enumerate(thetas):
        single = response(model, th, f, dt)
        np.testing.assert_allclose(batch[k], single, rtol=1e-12, atol=1e-14 * np.abs(single).max())


@pytest.mark.parametrize("dt", [None, 1 / 6.25e6])
def test_batch_equals_single_evaluation_over_the_search_box(dt):
    """Extreme shapes of the whole box (responses down to 1e-30 and below: modal sums cancel,
    the direct solve takes over) give the same values as one evaluation at a time (to the
    modal sums' error bound, PEAK_TOLERANCE of the peak), and agree with the direct solve at
    every line to 1e-8 of the peak, as python-control does in test_frequency_response (lines far
    below the peak may come from a modal sum that lost their own relative digits)."""
    model = _chain()
    rng = np.random.default_rng(2)
    lo, hi = np.log([1e4, 1e-4, 1e3, 1e-2]), np.log([1e14, 1e7, 1e14, 1e7])
    thetas = np.exp(lo + rng.uniform(size=(70, 4)) * (hi - lo))
    f = np.geomspace(30.0, 2e9 if dt is None else 3e6, 120)
    batch = response_batch(model, thetas, f, dt, block=16)
    for k, th in enumerate(thetas):
        single = response(model, th, f, dt)
        ref = _direct_response(as_float_ss(model.state_space(th)), f, dt)
        peak = np.abs(ref).max()
        np.testing.assert_allclose(batch[k], single, rtol=1e-12, atol=PEAK_TOLERANCE * peak)
        assert np.max(np.abs(single - ref)) <= 1e-8 * peak


def test_batch_with_one_grid_per_vector_and_small_blocks():
    model = _chain(4)
    thetas = _thetas(5, seed=3)
    grids = np.array([np.geomspace(1e3 * (k + 1), 1e6, 30) for k in range(5)])
    batch = response_batch(model, thetas, grids, block=2)  # several blocks
    for k, th in enumerate(thetas):
        np.testing.assert_allclose(batch[k], response(model, th, grids[k]), rtol=1e-8,
                                   atol=1e-10 * np.abs(batch[k]).max())


def test_batch_outside_the_domain_gives_nan_not_an_error():
    model = _chain(4)
    thetas = np.array([[3e8, 15.0, 5e7, 12.0], [np.nan, 15.0, 5e7, 12.0]])
    H = response_batch(model, thetas, np.geomspace(1e3, 1e6, 10))
    assert np.all(np.isfinite(H[0])) and np.all(np.isnan(H[1]))


def test_dtft_of_several_records_equals_the_direct_sum():
    from mbus_framework.estimation.spectral import dtft

    rng = np.random.default_rng(5)
    x = rng.standard_normal((2, 5000))
    dt = 1 / 6.25e6
    f = np.geomspace(1e3, 2e6, 37)
    ref = np.exp(-2j * np.pi * np.outer(f, np.arange(5000)) * dt) @ x.T
    both = dtft(x, f, dt, chunk=1000)
    np.testing.assert_allclose(both, ref.T, rtol=1e-10, atol=1e-10 * np.abs(ref).max())
    np.testing.assert_allclose(dtft(x[1], f, dt), ref[:, 1], rtol=1e-10, atol=1e-10 * np.abs(ref).max())
