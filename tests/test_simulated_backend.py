"""``simulated`` backend: a seeded virtual rig with explicit noise (DESIGN.md section 2)."""
from __future__ import annotations

import numpy as np
import pytest

from mbus_framework.interfaces.backend import AcquisitionContext
from mbus_framework.pipeline.config import validate_options
from mbus_framework.errors import ConfigError, PluginError
from mbus_framework.interfaces.plugin_manager import new_plugin_manager
from mbus_framework.interfaces.registry import Registry
from mbus_framework.interfaces.sample import Sample
from mbus_framework.engine.simulation import simulate
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

SAMPLE = Sample(0.05, 0.0254, 1000.0)
TRUTH = {"k_sigma": 3.0e8, "b_sigma": 15.0, "k_tau": 5.0e7, "b_tau": 12.0}
THETA = np.array(list(TRUTH.values()))


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_manager(new_plugin_manager())


@pytest.fixture(scope="module")
def waveform():
    return Prbs(PrbsOptions(order=9, bit_width=2.5e-6, sample_rate=6.25e6, n_samples=3000)).waveform()


def model(n: int = 6) -> KelvinVoigtChain:
    return KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=n))


def acquire(registry, waveform, options: dict, fitted=None):
    spec = registry.get("backend", "simulated")
    backend = spec.implementation(validate_options(spec.implementation.Options, options, "backend.options"))
    fitted = fitted or model()
    return backend.acquire(AcquisitionContext(waveform, SAMPLE, fitted, registry))


def noise_free(waveform, n: int = 6, theta=THETA) -> np.ndarray:
    return simulate(model(n), theta, waveform.u, waveform.dt)


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def test_noise_free_record_is_the_exact_simulation(registry, waveform):
    m = acquire(registry, waveform, {"truth": TRUTH, "noise": {"relative_std": 0.0}})
    np.testing.assert_array_equal(m.y, noise_free(waveform))
    np.testing.assert_array_equal(m.u, waveform.u)
    np.testing.assert_array_equal(m.t, waveform.t)
    assert m.truth == pytest.approx(TRUTH, rel=1e-15)
    assert m.meta["noise_std"] == 0.0


def test_same_seed_same_record_other_seed_other_noise(registry, waveform):
    opts = {"truth": TRUTH, "noise": {"relative_std": 0.1}, "seed": 11}
    a = acquire(registry, waveform, opts)
    b = acquire(registry, waveform, opts)
    c = acquire(registry, waveform, {**opts, "seed": 12})
    np.testing.assert_array_equal(a.y, b.y)
    assert not np.allclose(a.y, c.y)
    # Only the noise differs: same noise-free part.
    y0 = noise_free(waveform)
    assert rms(a.y - y0) == pytest.approx(rms(c.y - y0), rel=0.1)
    assert a.meta["seed"] == 11


@pytest.mark.parametrize("relative_std", [0.01, 0.05, 0.2])
def test_noise_std_is_relative_std_times_rms_of_noise_free_output(registry, relative_std):
    """Statistical check over 20000 samples: the std estimate has ~0.5 % relative SE, the
    tolerance is 3 % (6 SE); the mean is within 5 SE of 0; the noise is white and Gaussian."""
    w = Prbs(PrbsOptions(order=12, bit_width=2.5e-6, sample_rate=6.25e6, n_samples=20000)).waveform()
    m = acquire(registry, w, {"truth": TRUTH, "noise": {"relative_std": relative_std}, "seed": 5})
    y0 = noise_free(w)
    e = m.y - y0
    sigma = relative_std * rms(y0)
    assert m.meta["noise_std"] == pytest.approx(sigma, rel=1e-12)
    assert np.std(e) == pytest.approx(sigma, rel=0.03)
    assert abs(np.mean(e)) < 5 * sigma / np.sqrt(e.size)
    lag1 = float(np.corrcoef(e[:-1], e[1:])[0, 1])
    assert abs(lag1) < 5 / np.sqrt(e.size)
    # Gaussian: 95.45 % within 2 sigma (binomial SE 0.15 %).
    assert np.mean(np.abs(e) < 2 * sigma) == pytest.approx(0.9545, abs=0.008)


def test_absolute_std_overrides_relative(registry, waveform):
    m = acquire(registry, waveform, {"truth": TRUTH, "noise": {"relative_std": 0.5, "absolute_std": 1e-4}, "seed": 2})
    assert m.meta["noise_std"] == 1e-4
    assert np.std(m.y - noise_free(waveform)) == pytest.approx(1e-4, rel=0.1)


def test_input_noise_is_optional_and_explicit(registry, waveform):
    m = acquire(registry, waveform, {"truth": TRUTH, "noise": {"relative_std": 0.0, "input_relative_std": 0.02}})
    assert np.std(m.u - waveform.u) == pytest.approx(0.02 * rms(waveform.u), rel=0.1)
    # The output is still driven by the clean designed input.
    np.testing.assert_array_equal(m.y, noise_free(waveform))


def test_truth_as_properties_equals_truth_as_parameters(registry, waveform):
    props = model().to_properties(THETA)
    a = acquire(registry, waveform, {"truth": TRUTH, "seed": 3})
    b = acquire(registry, waveform, {"truth": props, "seed": 3})
    np.testing.assert_allclose(b.y, a.y, rtol=1e-12, atol=1e-12 * rms(a.y))
    assert b.truth == pytest.approx(TRUTH, rel=1e-12)
    assert b.meta["true_properties"] == pytest.approx(props, rel=1e-12)


def test_other_medium_gives_no_truth_for_the_fitted_model(registry, waveform):
    """A true medium with another element count is a different model: its parameters are not the
    fitted model's truth (only the material properties are comparable)."""
    opts = {
        "truth": model().to_properties(THETA),  # the same material, meshed finer
        "medium": {"name": "kelvin_voigt", "options": {"n_elements": 12}},
        "noise": {"relative_std": 0.0},
    }
    m = acquire(registry, waveform, opts, fitted=model(6))
    assert m.truth is None
    assert m.meta["medium"] == "kelvin_voigt"
    np.testing.assert_allclose(list(m.meta["true_parameters"].values()), model(12).from_properties(opts["truth"]))
    np.testing.assert_array_equal(m.y, noise_free(waveform, 12, model(12).from_properties(opts["truth"])))
    # The same element count through `medium` is the fitted model again: truth is known.
    same = acquire(registry, waveform, {**opts, "medium": {"name": "kelvin_voigt", "options": {"n_elements": 6}}})
    assert same.truth is not None


def test_unknown_medium_lists_the_choices(registry, waveform):
    with pytest.raises(PluginError) as info:
        acquire(registry, waveform, {"truth": TRUTH, "medium": {"name": "kelvin_vogt"}})
    assert "did you mean 'kelvin_voigt'" in str(info.value)
    assert "choose one of:" in str(info.value)


def test_bad_medium_options_name_the_key_path(registry, waveform):
    with pytest.raises(ConfigError) as info:
        acquire(registry, waveform, {"truth": TRUTH, "medium": {"name": "kelvin_voigt", "options": {"n_element": 3}}})
    assert "backend.options.medium.options.n_element" in str(info.value)
    assert "did you mean 'n_elements'" in str(info.value)


@pytest.mark.parametrize(
    "truth, fragment",
    [
        ({**TRUTH, "b_tua": 1.0}, "backend.options.truth.b_tua"),
        ({"k_sigma": 1.0, "b_sigma": 1.0, "k_tau": 1.0}, "missing b_tau"),
        ({"E_sigma": 1e9, "eta_sigma": 1.0, "E_tau": 1e8, "eta_tua": 1.0}, "did you mean 'eta_tau'"),
    ],
)
def test_bad_truth_is_a_config_error(registry, waveform, truth, fragment):
    with pytest.raises(ConfigError) as info:
        acquire(registry, waveform, {"truth": truth})
    assert fragment in str(info.value)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "options, fragment",
    [
        ({}, "backend.options.truth: required key is missing"),
        ({"truth": TRUTH, "noise": {"relative_std": -0.1}}, "backend.options.noise.relative_std"),
        ({"truth": TRUTH, "noise": {"kind": "uniform"}}, "backend.options.noise.kind"),
        ({"truth": TRUTH, "sed": 3}, "did you mean 'seed'"),
    ],
)
def test_bad_options_name_the_key_path(registry, options, fragment):
    spec = registry.get("backend", "simulated")
    with pytest.raises(ConfigError) as info:
        validate_options(spec.implementation.Options, options, "backend.options")
    assert fragment in str(info.value)


def test_foh_hold_changes_the_record(registry, waveform):
    z = acquire(registry, waveform, {"truth": TRUTH, "noise": {"relative_std": 0.0}})
    f = acquire(registry, waveform, {"truth": TRUTH, "noise": {"relative_std": 0.0}, "hold": "foh"})
    np.testing.assert_array_equal(f.y, simulate(model(), THETA, waveform.u, waveform.dt, "foh"))
    assert not np.allclose(z.y, f.y)
