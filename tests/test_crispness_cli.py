"""``mbus-analyze crispness`` and ``predict`` end to end on tables made from the physics:
files written, numbers consistent, the saved model reproduces the fit and scores new samples,
one-line errors with exit status 2."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from mbus_framework.analysis.cli import main
from mbus_framework.analysis.crispness.model import CrispnessModel
from mbus_framework.analysis.crispness.network import MLP, MinMaxScaling
from mbus_framework.analysis.crispness.regressor import LMNetworkRegressor
from virtual_apples import physics_table

FAST = ["--structures", "2,1-1", "--members", "2", "--restarts", "1", "--seed", "3"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("crisp")
    table, panel = physics_table(n=18, seed=1)
    table.to_csv(d / "properties.csv", index=False)
    panel.to_csv(d / "panel.csv", index=False)
    return d


@pytest.fixture(scope="module")
def analysis(files):
    out = files / "out"
    code = main(["crispness", str(files / "properties.csv"), "--scores", str(files / "panel.csv"), "--group", "cultivar",
                 "--inputs", "k_sigma,k_tau,b_sigma", "--compare-inputs", "k_sigma,k_tau", "-o", str(out), *FAST])
    assert code == 0
    return out


def test_crispness_writes_tables_plots_json_and_models(analysis, capsys):
    for name in ("panel_by_assessor.csv", "panel_by_group.csv", "anova_group.csv", "anova_assessor.csv", "lsd_assessor.csv",
                 "structures.csv", "loo_predictions.csv", "agreement.csv", "sensitivity.csv", "comparisons.csv",
                 "crispness.json", "report.txt", "model.json", "model_compare.json",
                 "measured_vs_predicted.png", "structures.png", "sensitivities.png", "panel.png"):
        assert (analysis / name).stat().st_size > 0, name
    doc = json.loads((analysis / "crispness.json").read_text())
    agree = pd.read_csv(analysis / "agreement.csv").set_index(["inputs", "model"])
    loo = pd.read_csv(analysis / "loo_predictions.csv").set_index("sample_id")
    first = doc["input_sets"][0]
    assert first["inputs"] == ["k_sigma", "k_tau", "b_sigma"]
    assert first["network"]["r"] == pytest.approx(agree.loc[("k_sigma,k_tau,b_sigma", "network"), "r"], rel=1e-12)
    assert first["network"]["r"] == pytest.approx(np.corrcoef(loo["measured"], loo["network [k_sigma,k_tau,b_sigma]"])[0, 1], rel=1e-10)
    assert doc["fisher_z"]["r1"] == pytest.approx(first["network"]["r"])
    assert doc["n_samples"] == 18 and len(doc["anova_group"]) == 3
    sens = pd.read_csv(analysis / "sensitivity.csv")
    assert set(sens.model) == {"network", "ridge"} and len(sens) == 2 * 3 + 2 * 2
    report = (analysis / "report.txt").read_text()
    assert "Table 7.3" in report and "Fisher's Z" in report and "ranks the inputs" in report


def test_saved_model_is_the_seeded_fit_and_predict_scores_a_table(analysis, files, tmp_path):
    table = pd.read_csv(files / "properties.csv")
    loo = pd.read_csv(analysis / "loo_predictions.csv").set_index("sample_id")
    model = CrispnessModel.load(analysis / "model.json")
    assert model.inputs == ["k_sigma", "k_tau", "b_sigma"]
    # the saved network is exactly what the documented estimator gives from the same seed
    ref = LMNetworkRegressor((6,), n_restarts=1, n_members=2, random_state=3)
    X = table.set_index("sample_id").loc[loo.index, model.inputs].to_numpy()
    ref.fit(X, loo["measured"].to_numpy())
    np.testing.assert_allclose(model.regressor.predict(X), ref.predict(X), rtol=1e-12)
    # predict on new samples (the table with one sample moved out of the training range)
    new = table.copy()
    new.loc[0, "k_sigma"] *= 10
    new.to_csv(tmp_path / "new.csv", index=False)
    assert main(["predict", str(tmp_path / "new.csv"), "--model", str(analysis / "model.json"), "-o", str(tmp_path / "pred.csv")]) == 0
    pred = pd.read_csv(tmp_path / "pred.csv", keep_default_na=False)
    np.testing.assert_allclose(pred.predicted[1:], ref.predict(new[model.inputs].to_numpy())[1:], rtol=1e-12)
    assert pred.extrapolated[0] == "k_sigma" and (pred.extrapolated[1:] == "").all()
    assert (pred.member_sd >= 0).all()


def test_model_file_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    X, y = rng.random((15, 3)) * [1e10, 1e3, 1e9], rng.random(15) * 9
    est = LMNetworkRegressor((3, 2), activation="logistic", n_restarts=1, n_members=3, random_state=1).fit(X, y)
    path = CrispnessModel(["a", "b", "c"], est, {"note": np.float64(1.5), "nan": float("nan")}).save(tmp_path / "m.json")
    back = CrispnessModel.load(path)
    for w1, w2 in zip(est.members_, back.regressor.members_):
        np.testing.assert_array_equal(w1, w2)
    np.testing.assert_allclose(est.predict(X), back.regressor.predict(X), rtol=1e-12, atol=0)
    assert back.training == {"note": 1.5, "nan": None}
    assert json.loads(path.read_text())["network"] == {"hidden_layer_sizes": [3, 2], "activation": "logistic", "output": "linear"}


def test_model_written_by_hand_scores_as_documented(tmp_path):
    """The file format alone defines the prediction: score = low + span * (W_o tanh(W_1 z + b_1) + b_o)."""
    W1, b1, Wo, bo = [[1.0, -2.0]], [0.5], [[2.0]], [-0.25]
    doc = {"format": "mbus-crispness-model", "version": 1, "inputs": ["k_sigma", "k_tau"],
           "input_scaling": {"low": [1e10, 1e8], "high": [3e10, 5e8]}, "output_scaling": {"low": 1.0, "high": 8.0},
           "network": {"hidden_layer_sizes": [1], "activation": "tanh"},
           "members": [{"layers": [{"W": W1, "b": b1}, {"W": Wo, "b": bo}]}]}
    (tmp_path / "m.json").write_text(json.dumps(doc))
    m = CrispnessModel.load(tmp_path / "m.json")
    table = pd.DataFrame({"sample_id": ["x"], "k_sigma": [2e10], "k_tau": [2e8]})
    z = np.array([0.5, 0.25])
    expected = 1.0 + 7.0 * (2.0 * np.tanh(z @ [1.0, -2.0] + 0.5) - 0.25)
    assert m.predict_table(table).predicted[0] == pytest.approx(expected, rel=1e-14)


@pytest.mark.parametrize("edit, words", [
    (lambda d: d.update(format="other"), ["not an mbus-crispness-model"]),
    (lambda d: d.update(version=2), ["version"]),
    (lambda d: d["members"][0]["layers"].pop(), ["members.0.layers", "do not fit"]),
    (lambda d: d["input_scaling"]["low"].pop(), ["input_scaling"]),
    (lambda d: d["network"].update(activation="relu"), ["network.activation"]),
])
def test_broken_model_files_are_one_line_errors(tmp_path, capsys, edit, words):
    est = LMNetworkRegressor.from_members(MLP(2, (2,)), [np.zeros(9)], MinMaxScaling(np.zeros(2), np.ones(2)),
                                          MinMaxScaling(np.zeros(1), np.ones(1)))
    doc = CrispnessModel(["k_sigma", "k_tau"], est).to_dict()
    edit(doc)
    (tmp_path / "m.json").write_text(json.dumps(doc))
    pd.DataFrame({"sample_id": ["a"], "k_sigma": [1.0], "k_tau": [1.0]}).to_csv(tmp_path / "t.csv", index=False)
    assert main(["predict", str(tmp_path / "t.csv"), "--model", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "m.json" in err
    for w in words:
        assert w in err


def _error(capsys, *argv) -> str:
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mbus-analyze: error:") and err.count("\n") == 0
    return err


def test_user_errors_are_one_line(files, analysis, tmp_path, capsys):
    t, p = files / "properties.csv", files / "panel.csv"
    assert "b_tau_x" in _error(capsys, "crispness", t, "--scores", p, "--inputs", "k_sigma,b_tau_x", "-o", tmp_path)
    bad = pd.read_csv(p)
    bad.loc[0, "sample_id"] = "pear7"
    bad.to_csv(tmp_path / "bad.csv", index=False)
    assert "'pear7'" in _error(capsys, "crispness", t, "--scores", tmp_path / "bad.csv", "-o", tmp_path)
    assert "--hidden" in _error(capsys, "crispness", t, "--scores", p, "--hidden", "six", "-o", tmp_path)
    assert "--structures" in _error(capsys, "crispness", t, "--scores", p, "--structures", "2,x", "-o", tmp_path)
    assert "nope.csv" in _error(capsys, "crispness", tmp_path / "nope.csv", "--scores", p)
    assert "not found" in _error(capsys, "predict", t, "--model", tmp_path / "none.json")
    pd.read_csv(t).drop(columns=["k_tau"]).to_csv(tmp_path / "less.csv", index=False)
    assert "k_tau" in _error(capsys, "predict", tmp_path / "less.csv", "--model", analysis / "model.json")


def test_command_defaults_match_the_library():
    from mbus_framework.analysis.crispness import command as crispness_command, validation as crispness, workflow as crispness_workflow

    assert crispness_workflow._structures(crispness_command.DEFAULT_STRUCTURES) == list(crispness.DEFAULT_STRUCTURES)
    est, cli = LMNetworkRegressor(), _args()
    assert (cli.restarts, cli.members, cli.validation_fraction, int(cli.hidden)) == (
        est.n_restarts, est.n_members, est.validation_fraction, est.hidden_layer_sizes[0])


def _args(*argv):
    import argparse

    from mbus_framework.analysis.crispness.command import add_arguments

    p = argparse.ArgumentParser()
    add_arguments(p, "crispness")
    return p.parse_args(["t.csv", "--scores", "p.csv", *argv])
