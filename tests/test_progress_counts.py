"""Honest progress: a fit that goes on past ``n_starts`` (record poles, fallback starts) raises
its total first, so the counter never reads "7/6"; studies get a display with an ETA."""
from __future__ import annotations

import io

import numpy as np

from mbus_framework.estimation.problem import FitProblem, Progress
from mbus_framework.pipeline.progress import LineProgress
from mbus_plugins.solvers.scipy_lm import ScipyLM, ScipyLMOptions
from test_compare import models, record


class Counting(Progress):
    def __init__(self):
        self.total, self.done, self.seen = None, 0, []

    def start(self, description, total=None):
        self.total, self.done = total, 0

    def set_total(self, total):
        self.total = total

    def advance(self, steps=1, note=""):
        self.done += steps
        self.seen.append((self.done, self.total))


def test_a_rejected_fit_never_counts_past_its_total():
    """Maxwell fitted to a Kelvin-Voigt record is never accepted: every phase runs."""
    data = record("kelvin_voigt")
    problem = FitProblem(models()["maxwell"], data.t, data.u, data.y)
    opts = {"strategy": {"n_starts": 2, "pole_starts": 2, "fallback_starts": 3, "widen": 0}}
    progress = Counting()
    fit = ScipyLM(ScipyLMOptions.model_validate(opts)).solve(problem, progress)
    assert not fit.strategy["accepted"]
    assert progress.done == len(fit.strategy["starts"]) > 2  # went on past n_starts
    assert all(done <= total for done, total in progress.seen), progress.seen


def test_line_progress_prints_an_eta_after_a_raised_total():
    out = io.StringIO()
    p = LineProgress(after=0.0, every=0.0, stream=out)
    p.start("global search (starts)", total=2)
    p.advance()
    p.set_total(4)
    p.advance()
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("global search (starts): 1/2, ETA ")
    assert lines[1].startswith("global search (starts): 2/4, ETA ")
    assert np.all(["elapsed" in line for line in lines])


def test_a_study_off_a_terminal_reports_progress_lines_with_an_eta(monkeypatch, tmp_path):
    import mbus_framework.studies.runner as runner
    from mbus_framework.cli import main

    got = {}

    class Done:
        text = "study done"

    def fake_run_study(kind, config, overrides, out, progress, **kw):
        got["progress"] = progress
        return Done()

    monkeypatch.setattr(runner, "run_study", fake_run_study)
    assert main(["tests/data/studies_small.yaml", "--study", "element_sweep", "-o", str(tmp_path / "s")]) == 0
    assert isinstance(got["progress"], LineProgress)  # stderr is not a terminal under pytest
    assert main(["tests/data/studies_small.yaml", "--study", "element_sweep", "-q", "-o", str(tmp_path / "q")]) == 0
    assert got["progress"] is None
