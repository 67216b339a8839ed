"""Region widening (:meth:`mbus_framework.estimation.strategy._Search.widen_if_on_edge`) stops
when nothing can widen or a refit does not lower the cost (the refits it skips would repeat
the last one)."""
from __future__ import annotations

import numpy as np

from mbus_framework.estimation.local import LocalResult
from mbus_framework.estimation.strategy import StrategyOptions, _Search
from tests.test_strategy import CASES, make_problem


def _search(problem, costs, calls, hard=None):
    """A search whose local fit returns its start with the next of ``costs`` (and counts)."""

    def fit(p, theta, band, max_nfev, final):
        calls.append((p.lower.copy(), p.upper.copy()))
        return LocalResult(np.asarray(theta, float), costs[min(len(calls) - 1, len(costs) - 1)], 1, 1, 1, "", 1)

    s = _Search(problem, fit, StrategyOptions(widen=3), None)
    if hard is not None:
        s._hard = hard
    return s


def _on_lower_edge(s):
    theta = s.problem.lower.copy()
    theta[~s.space.movable] = s.problem.upper[~s.space.movable]
    return LocalResult(theta, 1.0, 1, 1, 1, "", 1)


def test_no_refit_when_the_region_is_already_at_its_hard_bounds():
    problem, _ = make_problem(CASES["thin-stiff"])
    calls: list = []
    s = _search(problem, [0.5], calls)
    s._hard = (s.problem.lower.copy(), s.problem.upper.copy())  # nothing may widen
    out = s.widen_if_on_edge(_on_lower_edge(s))
    assert calls == [] and out.cost == 1.0 and s.report.widened == []


def test_widening_stops_when_a_refit_does_not_lower_the_cost():
    problem, _ = make_problem(CASES["thin-stiff"])
    calls: list = []
    s = _search(problem, [2.0], calls)
    start = _on_lower_edge(s)
    lo0 = s.problem.lower.copy()
    # a refit that stays on the (new) edge but costs more: before, widening went on (3 refits)
    s.local_fit = lambda p, th, band, n, final: (calls.append(1), LocalResult(p.lower.copy(), 2.0, 1, 1, 1, "", 1))[1]
    out = s.widen_if_on_edge(start)
    assert len(calls) == 1 and out is start
    mv = s.space.movable & (lo0 > s._hard[0])
    assert np.all(s.problem.lower[mv] < lo0[mv])  # the region did widen once


def test_a_refit_that_lowers_the_cost_is_kept_and_widening_goes_on():
    problem, _ = make_problem(CASES["thin-stiff"])
    calls: list = []
    s = _search(problem, [0.5], calls)
    s.local_fit = lambda p, th, band, n, final: (calls.append(1), LocalResult(p.lower.copy(), 1.0 / (2 + len(calls)),
                                                                              1, 1, 1, "", 1))[1]
    out = s.widen_if_on_edge(_on_lower_edge(s))
    assert len(calls) >= 2 and out.cost < 1.0
