"""The memo of rejected modal outputs: a Jacobian at the theta whose modal y was just rejected
skips the modal sensitivity kernels and gives exactly what the uncached call gives."""
from __future__ import annotations

import numpy as np
import pytest

from mbus_framework.engine import modal_response, simulation as sim
from mbus_framework.interfaces.sample import Sample
from mbus_plugins.models.kelvin_voigt import KelvinVoigtChain, KelvinVoigtOptions

DT = 1.0 / 6.25e6
#: the convergence benchmark's kidney (5 cm, 1040 kg/m^3): its modal y is rejected on these records
THETA = np.array([1.9964274676441406e11, 1.945756719734391e4, 2.2183414045528247e11, 4.277089902303288e4])
#: Table 3.1 (5 cm, 1000 kg/m^3): its modal y is accepted
TABLE_3_1 = np.array([3.0e8, 15.0, 5.0e7, 12.0])


def model(density=1040.0):
    return KelvinVoigtChain(Sample(length=0.05, diameter=0.0254, density=density), KelvinVoigtOptions(n_elements=10))


def prbs(N=6200, seed=0):
    bits = np.random.default_rng(seed).choice([-1.0, 1.0], size=-(-N // 16))
    return np.repeat(bits, 16)[:N]


def _fresh_sens(m, theta, u, hold):
    sim._REJECTED.clear()
    return sim.simulate_with_sensitivities(m, theta, u, DT, hold)


@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_memo_gives_the_uncached_result(hold, monkeypatch):
    m, u = model(), prbs()
    ss = sim.as_float_ss(m.state_space(THETA))
    assert sim.engine_path(ss, DT, u=u, hold=hold) == "doubling"  # this record rejects the modal y
    y_ref, J_ref = _fresh_sens(m, THETA, u, hold)
    calls = []
    monkeypatch.setattr(sim, "modal_kernels", lambda *a, **k: calls.append(1) or pytest.fail("modal kernels formed"))
    sim.simulate(m, THETA, u, DT, hold)  # rejects and remembers
    y, J = sim.simulate_with_sensitivities(m, THETA, u, DT, hold)
    assert not calls
    np.testing.assert_array_equal(y, y_ref)
    np.testing.assert_array_equal(J, J_ref)


def test_memo_is_keyed_by_system_step_hold_and_input():
    m, u = model(), prbs()
    sim._REJECTED.clear()
    sim.simulate(m, THETA, u, DT, "zoh")
    mf = sim.modal_form(sim.as_float_ss(m.state_space(THETA)))
    assert sim._rejected_before(mf, DT, "zoh", u.copy())
    assert not sim._rejected_before(mf, DT, "foh", u)
    assert not sim._rejected_before(mf, 2 * DT, "zoh", u)
    v = u.copy()
    v[100] = -v[100]
    assert not sim._rejected_before(mf, DT, "zoh", v)
    other = sim.modal_form(sim.as_float_ss(m.state_space(THETA * 1.01)))
    assert not sim._rejected_before(other, DT, "zoh", u)
    u[5] = 0.5  # an in-place change of the caller's array is seen (the memo keeps a copy)
    assert not sim._rejected_before(mf, DT, "zoh", u)


def test_accepted_modal_output_is_not_remembered():
    m, u = model(1000.0), prbs()
    ss = sim.as_float_ss(m.state_space(TABLE_3_1))
    assert sim.engine_path(ss, DT, u=u) == "modal"
    sim._REJECTED.clear()
    sim.simulate(m, TABLE_3_1, u, DT)
    assert not sim._REJECTED
    assert not sim._rejected_before(sim.modal_form(ss), DT, "zoh", u)


def _fresh_y(m, theta, u, hold):
    sim._REJECTED.clear()
    sim._LAST_Y_PATH.clear()
    return sim.simulate(m, theta, u, DT, hold)


@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_doubling_first_gives_the_same_output(hold, monkeypatch):
    m, u = model(), prbs()
    y_ref = _fresh_y(m, THETA, u, hold)  # modal tried, rejected: doubling
    assert sim._expect_doubling(DT, hold, u)
    theta = THETA * np.array([1.01, 0.99, 1.02, 0.98])
    y_fresh = _fresh_y(m, theta, u, hold)
    sim.simulate(m, THETA, u, DT, hold)  # the record is known to take the doubling path
    monkeypatch.setattr(sim, "modal_block_response", lambda *a: pytest.fail("modal y formed"))
    np.testing.assert_array_equal(sim.simulate(m, THETA, u, DT, hold), y_ref)
    np.testing.assert_array_equal(sim.simulate(m, theta, u, DT, hold), y_fresh)


def test_prediction_does_not_change_an_accepted_modal_output():
    kid, tab, u = model(), model(1000.0), prbs()
    y_ref = _fresh_y(tab, TABLE_3_1, u, "zoh")
    assert sim.engine_path(sim.as_float_ss(tab.state_space(TABLE_3_1)), DT, u=u) == "modal"
    sim.simulate(kid, THETA, u, DT)  # last path on this record: doubling
    assert sim._expect_doubling(DT, "zoh", u)
    np.testing.assert_array_equal(sim.simulate(tab, TABLE_3_1, u, DT), y_ref)
    assert not sim._expect_doubling(DT, "zoh", u)  # the modal acceptance is remembered


@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_bounds_match_the_block_recursion(hold):
    m, u = model(), prbs()
    mf = sim.modal_form(sim.as_float_ss(m.state_space(THETA)))
    y, amp = modal_response.modal_block_response(mf, DT, hold, u)
    assert modal_response.output_amplification(y, *modal_response.modal_y_bounds(mf, DT, hold, u.size), u) == amp


def test_surely_rejected_keeps_a_margin():
    u = prbs()
    T = sim.MODAL_MAX_AMPLIFICATION
    assert sim._surely_rejected(2 * T / 25.0, 25.0, u)
    assert not sim._surely_rejected(T / 25.0 * (1 + 1e-9), 25.0, u)  # borderline: decided by the modal y
    assert not sim._surely_rejected(np.inf, 25.0, u) and not sim._surely_rejected(0.0, 25.0, u)
