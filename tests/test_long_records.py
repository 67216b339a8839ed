"""Long records (issue 24): the time budget bounds the whole search, the record-length
dependent steps are linear, and a decimated or windowed record can be fitted.

No timing assertions: the budget is tested with a fake clock (or a budget smaller than one
evaluation) and linear scaling by the sizes of the arrays the steps build."""
from __future__ import annotations

import numpy as np
import pytest

from mbus_framework.api.fitting import fit
from mbus_framework.engine import physics
from mbus_framework.engine.moving import moving_average
from mbus_framework.engine.simulation import simulate
from mbus_framework.errors import ConfigError
from mbus_framework.estimation import poles, strategy, strategy_options
from mbus_framework.estimation.problem import FitProblem, Progress
from mbus_framework.estimation.spectral import excited_band
from mbus_framework.estimation.strategy import StrategyOptions, search
from mbus_framework.interfaces.backend import Measurement
from mbus_framework.interfaces.sample import Sample
from mbus_framework.pipeline import dispersion
from mbus_framework.pipeline.config import EstimationConfig
from mbus_framework.pipeline.reduction import decimate, reduce_record
from mbus_framework.pipeline.run import load_components
from mbus_plugins.excitations.prbs import Prbs, PrbsOptions
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions
from mbus_plugins.solvers.scipy_lm import ScipyLM, ScipyLMOptions

SAMPLE = Sample(0.03, 0.0254, 1080.0)
PROPS = {"E_sigma": 2.42e10, "eta_sigma": 7.18e3, "E_tau": 6.56e9, "eta_tau": 5.14e3}


def potato(n_samples: int = 2000, n_elements: int = 4, seed: int = 7):
    """A small simulated potato record (3 % noise) and its true parameters."""
    model = KelvinVoigtChain(SAMPLE, KelvinVoigtOptions(n_elements=n_elements))
    truth = model.from_properties(PROPS)
    w = Prbs(PrbsOptions(order=9, bit_width=0.4e-6, sample_rate=25e6, n_samples=n_samples)).waveform()
    y0 = simulate(model, truth, w.u, w.dt)
    y = y0 + np.random.default_rng(seed).normal(0, 0.03 * np.sqrt(np.mean(y0 ** 2)), y0.size)
    return model, truth, w, y


def mismatched(period: int = 250, repeats: int = 8):
    """The issue's mismatched record, small: the first ``period`` samples repeated, so every
    period restarts a transient the model cannot explain."""
    model, _, w, y = potato()
    return FitProblem(model, np.arange(period * repeats) * w.dt, np.tile(w.u[:period], repeats),
                      np.tile(y[:period], repeats))


class FakeClock:
    """time.perf_counter that advances 1 s per call: the budget runs out after a known
    number of clock readings, whatever the machine's speed."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        self.now += 1.0
        return self.now


class Notes(Progress):
    def __init__(self) -> None:
        self.notes: list[str] = []

    def advance(self, steps: int = 1, note: str = "") -> None:
        self.notes.append(note)


def test_budget_stops_a_search_between_evaluations(monkeypatch):
    problem = mismatched()
    clock = FakeClock()
    monkeypatch.setattr(strategy_options, "_now", clock)
    evaluations_after = []
    budget = 300.0

    def counting_fit(p, theta, band, max_nfev, final):
        def watch():
            p.monitor()  # raises once the budget has run out: the evaluation does not go ahead
            # it went ahead: the monitor's budget check (the first of its up to three clock
            # readings) must have passed, so at most budget + 3 readings have been made
            if clock.now > budget + 3:
                evaluations_after.append(clock.now)

        import dataclasses

        return solver._local_fit(dataclasses.replace(p, monitor=watch), theta, band, max_nfev, final)

    solver = ScipyLM(ScipyLMOptions(strategy=StrategyOptions(time_budget=budget)))
    progress = Notes()
    best, report, nfev, _ = search(problem, counting_fit, solver.options.strategy, progress)
    assert evaluations_after == []
    assert not report.accepted
    assert report.stopped_by_budget is not None
    assert "time budget of 300 s (CPU) ran out" in report.stopped_by_budget
    assert "solver.options.strategy.time_budget" in report.stopped_by_budget
    assert report.accepted_because.startswith("not confirmed: the time budget of 300 s (CPU) ran out")
    ended = [e["cost"] for e in report.starts if "end" in e]
    stopped = [e for e in report.starts if e.get("stopped") == "time budget ran out"]
    assert ended and len(stopped) == 1 and stopped[0]["evaluations"] > 0
    assert best.cost <= min(ended) and nfev > stopped[0]["evaluations"]
    assert any("s left" in n for n in progress.notes)  # the live note: evaluations, time, time left


def test_budget_smaller_than_one_evaluation_still_ends_with_an_honest_verdict():
    model, _, w, y = potato(n_samples=1000)
    r = fit(w.t, w.u, y, sample={"length": 0.03, "diameter": 0.0254, "density": 1080.0},
            model_options={"n_elements": 4}, solver_options={"strategy": {"time_budget": 1e-9}}, plots=False)
    stopped = [x for x in r.warnings if x.startswith("the search was stopped")]
    assert len(stopped) == 1
    assert "time budget of 1e-09 s (CPU) ran out after 0 local fit(s)" in stopped[0]
    assert "raise solver.options.strategy.time_budget" in stopped[0]
    assert r.document["strategy"]["accepted"] is False
    assert not r.success


def test_moving_average_equals_convolution_and_is_linear():
    rng = np.random.default_rng(3)
    for n, w in [(1, 1), (10, 3), (10, 4), (1000, 1), (1000, 7), (1000, 64), (1001, 1001)]:
        x = rng.random(n)
        np.testing.assert_allclose(moving_average(x, w), np.convolve(x, np.ones(w) / w, mode="same"),
                                   rtol=1e-10, atol=1e-12)
    with pytest.raises(ValueError):
        moving_average(np.ones(4), 0)


def test_record_length_steps_build_no_record_squared_work(monkeypatch):
    """The smoothing widths grow with the record: the steps must not convolve with them."""
    model, truth, w, y = potato(n_samples=200_000, n_elements=4)
    t, u = w.t, w.u
    short = physics.first_arrival_time(t[:5000], u[:5000], y[:5000])

    def refuse(*args, **kwargs):
        raise AssertionError("np.convolve with a record-length kernel (quadratic) was used")

    monkeypatch.setattr(np, "convolve", refuse)
    lo, hi = excited_band(u, w.dt)
    assert 0 < lo < hi
    assert physics.first_arrival_time(t, u, y) == pytest.approx(short, rel=0.1)
    assert dispersion.input_band(u, w.dt) is not None


def test_record_poles_factorise_in_chunks_of_bounded_size(monkeypatch):
    """The block-Hankel data matrix (4s x N) is never built whole: every QR sees at most
    chunk + 4s rows whatever N, and the factor equals the one of the whole matrix."""
    rng = np.random.default_rng(1)
    from scipy.signal import lfilter

    u = rng.standard_normal(30_000)
    y = lfilter([0, 0.5, 0.2], [1, -1.2, 0.8], u) + 0.01 * rng.standard_normal(u.size)
    s, cols = 8, u.size - 16 + 1
    M = np.vstack([poles._block_hankel(u, s, cols, s), poles._block_hankel(u, s, cols, 0),
                   poles._block_hankel(y, s, cols, 0), poles._block_hankel(y, s, cols, s)])
    whole = np.linalg.qr(M.T, mode="r")
    shapes = []
    qr = np.linalg.qr

    def recording_qr(a, mode="reduced"):
        shapes.append(a.shape)
        return qr(a, mode=mode)

    monkeypatch.setattr(poles.np.linalg, "qr", recording_qr)
    chunked = poles._lq_factor(u, y, s, cols, chunk=1000)
    assert max(r for r, _ in shapes) <= 1000 + 4 * s
    np.testing.assert_allclose(np.abs(chunked), np.abs(whole), rtol=1e-8, atol=1e-9 * np.abs(whole).max())
    z = poles.record_poles(u, y, 2)
    np.testing.assert_allclose(np.sort_complex(z), np.sort_complex(np.roots([1, -1.2, 0.8])), atol=1e-3)


@pytest.mark.parametrize("overrides, message", [
    (["estimation.decimate=0"], "configs/potato.yaml: estimation.decimate: Input should be greater than or equal to 1"),
    (["estimation.decimate=2.5"], "configs/potato.yaml: estimation.decimate:"),
    (["estimation.window=[2e-4, 1e-4]"], "configs/potato.yaml: estimation.window: [0.0002, 0.0001] must satisfy"),
    (["estimation.window=[0]"], "configs/potato.yaml: estimation.window: [0.0] must be two times [start_s, stop_s]"),
    (["estimation.decimat=2"], "did you mean 'decimate'"),
])
def test_estimation_options_are_validated_in_one_line(overrides, message):
    with pytest.raises(ConfigError) as err:
        load_components("configs/potato.yaml", overrides)
    assert message in str(err.value)
    assert "\n" not in str(err.value)


def test_reduction_that_leaves_too_little_is_a_one_line_error():
    t = np.arange(1000) * 1e-6
    m = Measurement(t, np.ones(1000), np.ones(1000))
    with pytest.raises(ConfigError, match=r"^run.yaml: estimation.decimate: 100 leaves 0 of 1000 samples"):
        reduce_record(m, EstimationConfig(decimate=100), "run.yaml")
    with pytest.raises(ConfigError, match=r"^run.yaml: estimation.window: \[2, 3\] s holds 0 samples"):
        reduce_record(m, EstimationConfig(window=[2.0, 3.0]), "run.yaml")


def test_decimation_keeps_a_linear_model_exact_in_band():
    """Filtering input and output with the same zero-phase FIR keeps y = H u: the model driven by
    the decimated input reproduces the decimated output (to the hold's in-band error), and the
    fitted properties of a decimated potato record are the full record's."""
    model, truth, w, y = potato(n_samples=5000, n_elements=4)
    y0 = simulate(model, truth, w.u, w.dt)
    q = 2
    ud, yd = decimate(w.u, q), decimate(y0, q)
    assert ud.size == yd.size == (5000 - 10 * q + q - 1) // q
    yhat = simulate(model, truth, ud, q * w.dt)
    assert np.linalg.norm(yhat - yd) <= 0.1 * np.linalg.norm(yd)
    # the record reduced by a window and a decimation is fitted and reported
    r = fit(w.t, w.u, y, sample={"length": 0.03, "diameter": 0.0254, "density": 1080.0},
            model_options={"n_elements": 4}, config={"estimation": {"decimate": q, "window": [0.0, 1.6e-4]}},
            plots=False)
    red = r.document["reduction"]
    assert red["n_samples"] == [5000, (4000 - 10 * q + q - 1) // q] and red["dt_s"] == pytest.approx(q * w.dt)
    for name, value in PROPS.items():
        assert float(r.properties[name]) == pytest.approx(value, rel=0.1), name
