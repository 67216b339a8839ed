"""The search decides how a start is fitted from explicit flags, never from its report label."""
from __future__ import annotations

import numpy as np

from mbus_framework.estimation.local import LocalResult
from mbus_framework.estimation.strategy import StrategyOptions, _Search
from tests.test_strategy import CASES, cost_at, make_problem


def _recording_fit(calls: list):
    def local(problem, theta0, band, max_nfev, final):
        calls.append((max_nfev, final))
        theta = np.asarray(theta0, float)
        return LocalResult(theta, cost_at(problem, theta), nfev=1, njev=1, status=1, message="scripted", iterations=1)
    return local


def test_as_given_flag_not_the_label_decides_the_full_precision_solve():
    """The user's values as given get a short (2 stage_max_nfev), non-final fit; any other
    start fitted in the frequency domain a full-precision one (10 stage_max_nfev), whatever
    its origin text says."""
    problem, truth = make_problem(CASES["thin-stiff"])
    calls: list = []
    s = _Search(problem, _recording_fit(calls), StrategyOptions(bands=[], stage_max_nfev=30), None)
    s.try_start(truth, "config (as given)", as_given=False)
    s.try_start(truth, "scan", as_given=True)
    assert calls == [(300, True), (60, False)]
    assert [st["origin"] for st in s.report.starts] == ["config (as given)", "scan"]
