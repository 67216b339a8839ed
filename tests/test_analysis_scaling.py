"""Analyses that scale (issue 24): the closed-form LDA leave-one-out against scikit-learn's
brute force, K-fold above the documented sizes (named in the output), sampled plots, line
progress and the JSON writer. No timings here: benchmarks/analysis_benchmark.py measures them."""
from __future__ import annotations

import io
import json

import numpy as np
import pandas as pd
import pytest

from fakes.campaign_tables import TABLE_4_2, grouped_table
from mbus_framework.analysis.classify import model as classify_model
from mbus_framework.analysis.classify.loo import closed_form_loo
from mbus_framework.analysis.classify.plots import drawn_samples
from mbus_framework.analysis.cli import main
from mbus_framework.analysis.outputs import write_json
from mbus_framework.pipeline.progress import LineProgress


def _brute_force(X, labels, k):
    from sklearn.discriminant_analysis import LinearDiscriminantAnalysis
    from sklearn.model_selection import LeaveOneOut, cross_val_predict

    return cross_val_predict(LinearDiscriminantAnalysis(priors=np.full(k, 1.0 / k)), X, labels, cv=LeaveOneOut())


@pytest.mark.parametrize("seed", range(12))
def test_closed_form_loo_equals_sklearn_leave_one_out(seed):
    rng = np.random.default_rng(seed)
    k, p = int(rng.integers(2, 6)), int(rng.integers(1, 5))
    n = int(rng.integers(3 * k, 70))
    labels = np.r_[np.arange(k), np.arange(k), rng.integers(0, k, n - 2 * k)]
    # overlapping groups (so that some samples are misclassified), features on scales 1e-3..1e3
    X = (rng.normal(size=(n, p)) + labels[:, None] * rng.normal(size=p) * 0.8) * 10 ** rng.uniform(-3, 3, p)
    fast = closed_form_loo(X, labels, k)
    assert fast is not None
    brute = _brute_force(X, labels, k)
    assert np.array_equal(fast, brute)


def test_singular_covariance_falls_back_to_refits_like_sklearn():
    rng = np.random.default_rng(3)
    labels = np.repeat(np.arange(3), 8)
    x = rng.normal(size=24) + labels
    X = np.c_[x, 2 * x + 1]  # collinear: the pooled covariance is singular
    assert closed_form_loo(X, labels, 3) is None
    predicted, validation = classify_model.lda_loo_predict(X, labels, 3)
    assert validation == "leave-one-out"
    assert np.array_equal(predicted, _brute_force(X, labels, 3))


def test_refits_above_the_size_limit_use_named_k_fold(monkeypatch, tmp_path, capsys):
    df = grouped_table(TABLE_4_2, 12, seed=2)
    df["E_twice"] = 2.0 * df["E_sigma"]  # with E_sigma: singular covariance, so LDA is refitted
    monkeypatch.setattr(classify_model, "REFIT_LOO_MAX", 20)
    path = tmp_path / "t.csv"
    df.to_csv(path, index=False)
    code = main(["classify", str(path), "--by", "material", "--sets", "E_sigma,E_twice", "E_tau",
                 "--out", str(tmp_path / "o"), "--no-plots"])
    assert code == 0
    out = capsys.readouterr().out
    doc = json.loads((tmp_path / "o" / "classification.json").read_text())
    assert doc["results"]["lda"]["E_sigma, E_twice"]["validation"] == "stratified 10-fold"
    assert doc["results"]["lda"]["E_tau"]["validation"] == "leave-one-out"  # closed form at any size
    assert "stratified 10-fold" in doc["lda"]["validation"] and "stratified 10-fold" in out


def test_small_tables_say_leave_one_out(tmp_path, capsys):
    path = tmp_path / "t.csv"
    grouped_table(TABLE_4_2, 4, seed=1).to_csv(path, index=False)
    assert main(["classify", str(path), "--by", "material", "--out", str(tmp_path / "o"), "--no-plots"]) == 0
    assert "LDA validation: leave-one-out" in capsys.readouterr().out
    assert json.loads((tmp_path / "o" / "classification.json").read_text())["lda"]["validation"] == "leave-one-out"


def test_plots_draw_a_proportional_subset_of_large_tables():
    labels = np.r_[np.zeros(9000, int), np.ones(990, int), np.full(10, 2)]
    mask = drawn_samples(labels, 2000)
    assert abs(mask.sum() - 2000) <= 3
    assert [int(mask[labels == g].sum()) for g in range(3)] == [1800, 198, 2]
    assert drawn_samples(labels[:1500], 2000).all()
    assert np.array_equal(mask, drawn_samples(labels, 2000))  # seeded


def test_crispness_validation_choice():
    from mbus_framework.analysis.crispness.validation import LOO_MAX, validation_for

    assert validation_for(LOO_MAX) == ("leave-one-out", None)
    assert validation_for(LOO_MAX + 1) == ("5-fold cross-validation", 5)


def test_k_fold_predicts_every_sample_once_out_of_fold():
    from sklearn.linear_model import LinearRegression

    from mbus_framework.analysis.crispness.validation import cross_validate

    rng = np.random.default_rng(0)
    X = rng.normal(size=(50, 2))
    y = X @ [1.0, -2.0] + 0.1 * rng.normal(size=50)
    res = cross_validate(LinearRegression(), X, y, seed=1, folds=5, keep_models=True)
    assert len(res.fold_models) == 5
    # each prediction comes from the one model that did not see the sample
    hits = [sum(np.isclose(m.predict(X[i:i + 1])[0], res.predictions[i], rtol=0, atol=1e-12) for m in res.fold_models)
            for i in range(50)]
    assert min(hits) >= 1 and np.corrcoef(res.predictions, y)[0, 1] > 0.99


def test_crispness_above_the_size_limit_uses_and_names_k_fold(monkeypatch, tmp_path):
    from mbus_framework.analysis.crispness import validation
    from virtual_apples import physics_table

    table, panel = physics_table(n=20, seed=2)
    table.to_csv(tmp_path / "t.csv", index=False)
    panel.to_csv(tmp_path / "p.csv", index=False)
    monkeypatch.setattr(validation, "LOO_MAX", 10)
    monkeypatch.setattr(validation, "STRUCTURE_SUBSET", 15)
    code = main(["crispness", str(tmp_path / "t.csv"), "--scores", str(tmp_path / "p.csv"), "--group", "cultivar",
                 "--structures", "2", "--members", "1", "--restarts", "1", "--no-plots", "-o", str(tmp_path / "o")])
    assert code == 0
    doc = json.loads((tmp_path / "o" / "crispness.json").read_text())
    assert doc["validation"] == "5-fold cross-validation"
    assert doc["structure_validation"] == "5-fold cross-validation on a random subset of 15 of 20 samples"
    report = (tmp_path / "o" / "report.txt").read_text()
    assert "validation: 5-fold cross-validation" in report and "Out-of-sample prediction (5-fold" in report


def test_line_progress_is_silent_for_short_work_and_shows_eta_for_long():
    quiet, loud = io.StringIO(), io.StringIO()
    p = LineProgress(after=60.0, every=0.0, stream=quiet)
    p.start("short", total=3)
    p.advance(1)
    p.stop()
    assert quiet.getvalue() == ""
    p = LineProgress(after=0.0, every=0.0, stream=loud)
    p.start("folds", total=4)
    p.advance(1)
    p.stop()
    assert loud.getvalue().startswith("folds: 1/4, ETA ")


def test_large_json_is_compact_and_equal(tmp_path, monkeypatch):
    from mbus_framework.analysis import outputs

    data = {"a": np.arange(5), "b": {"x": np.float64(1.5)}, "c": [float("nan")], "d": "s"}
    monkeypatch.setattr(outputs, "COMPACT_ABOVE", 10)
    write_json(tmp_path / "nan.json", data)  # NaN: the indented path writes null
    assert json.loads((tmp_path / "nan.json").read_text())["c"] == [None]
    del data["c"]
    write_json(tmp_path / "big.json", data)
    text = (tmp_path / "big.json").read_text()
    assert "\n " not in text and json.loads(text) == {"a": [0, 1, 2, 3, 4], "b": {"x": 1.5}, "d": "s"}


def test_constant_property_column_is_a_one_line_error(tmp_path, capsys):
    df = grouped_table(TABLE_4_2, 4, seed=1)
    df["eta_tau"] = 5.0e5
    path = tmp_path / "t.csv"
    df.to_csv(path, index=False)
    assert main(["classify", str(path), "--by", "material", "--out", str(tmp_path / "o"), "--no-plots"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "'eta_tau'" in err and "same value" in err


def test_k_fold_in_parallel_processes_gives_the_serial_result():
    from mbus_framework.analysis.crispness.regressor import LMNetworkRegressor
    from mbus_framework.analysis.crispness.validation import cross_validate

    rng = np.random.default_rng(4)
    X = rng.uniform(1.0, 2.0, size=(40, 2))
    y = np.tanh(X[:, 0] - X[:, 1]) + 0.05 * rng.normal(size=40)
    est = LMNetworkRegressor(hidden_layer_sizes=(2,), n_restarts=1, n_members=1)
    serial = cross_validate(est, X, y, seed=5, folds=4, n_jobs=1).predictions
    parallel = cross_validate(est, X, y, seed=5, folds=4, n_jobs=2).predictions
    assert np.array_equal(serial, parallel)
